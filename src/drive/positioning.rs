//! Positioning: moves on a finite stroke through zero speed, with a position estimate.
//!
//! ## Modes
//! - **Low-speed mode** ([`DriveState::LowSpeed`]) while the reference speed is below
//!   [`MotionConfig::low_speed_m_per_s`]: no back-EMF estimate is trusted there, so the
//!   drive imposes a current vector along the d axis of the *reference* position:
//!   angle `theta_ls = theta_anchor + pi (x_ref - x_anchor - x_pending) / tau`, anchored
//!   on the mover's angle and estimated position as the mode is entered; `x_pending`, the
//!   reference's lead on the mover at that instant (what the running loops trailed by),
//!   is taken up at the position loop's gain `k_x`, so the frame does not jump and the
//!   move still ends on its target. The mover is held on
//!   that vector like a stepper's rotor: a spring of stiffness `K_f I pi / tau` (N/m);
//!   at a force `F` it trails by `asin(F / (K_f I))`, restoring both ways (it
//!   accelerates and brakes alike) and never slipping a pole while `|F| < K_f I`.
//!   - Amplitude: [`MotionConfig::low_speed_current_a`] at rest, falling linearly with
//!     the reference speed to [`MotionConfig::exit_current_a`] at the band's edge:
//!     stiffness and accuracy at rest, and at the exit a small `I_d`, which a resistance
//!     error turns into an estimator angle error of `dR I_d / (w psi_f)`.
//!   - Damping: the spring and the moving mass ring at `w_n = sqrt(K_f I pi / (tau M))`
//!     (8.6 Hz on the paper axis at 5.9 A) with nothing but friction to damp them. The
//!     mover's speed is read from the q voltage (in the frame turning at `w_frame`,
//!     `u_q = Rs i_q + w_frame Ld i_d + w psi_f cos(delta)`; the inverter's error lies
//!     along the current, d), and the vector is retarded by `1.4 / w_n` times the speed
//!     error: damping ratio 0.7. The frame turns at the reference speed less the
//!     retard's rate, filtered at the current loop's bandwidth (the rate at which the
//!     loop turns the current with the frame): without that term a change of the retard
//!     reads as a speed `Ld I / psi_f` times its rate, a loop from the retard through the
//!     current loop back to the retard whose gain above the speed filter's corner is
//!     `(1.4 / w_n) 5 w_n Ld I / psi_f = 7 Ld I / psi_f` (2.2 on the paper motor, 24 on
//!     `motors/high_inductance.toml`, where it oscillated at the voltage limit and
//!     tripped `CURRENT_CONTROL`).
//!   - At rest a decaying dither of the vector (twice the learned friction's load angle,
//!     0.8 `w_n`, over three periods) frees the mover from where friction stopped it.
//!   - The estimator keeps running and is told the commanded acceleration.
//!   - Slip supervision: a load beyond `K_f I` pushes the mover off the vector, pole
//!     after pole, while the position estimate follows the vector. The q voltage's
//!     speed reading `w cos(delta)` shows it once the mover outruns the inverter's error
//!     (`w_ls`): moving, a reading against the reference's direction (the mover past
//!     the spring's peak, 90 deg from the vector); at rest, a reading beyond a held
//!     swing (`w_n + w_ls`); either way, a filtered magnitude of the reading beyond
//!     the reference speed plus that swing (a mover slipping pole after pole, whose
//!     signed reading averages out; not while the current loops have lost control,
//!     which the current-control supervision names). `OVERLOAD` then, not an
//!     unannounced runaway. (Not before the mover moves: at rest a non-salient motor
//!     shows no sign of where it sits on the spring.)
//! - **Sensorless** ([`DriveState::Running`]) above `low_speed_exit_ratio` times the
//!   threshold: the position loop `v_cmd = v_ref + k_x (x_ref - x_hat)`, within the
//!   profile's speed limit, feeds the speed loop (a mover behind its reference catches up
//!   on the deceleration, not past the axis's top speed); the profile's acceleration is
//!   fed forward as thrust current (`M a_ref / K_f`, slewed) and to the estimator's
//!   notch. The thrust the axis needs beyond that (friction, load) is learned here,
//!   along the motion. A lock loss falls back to the low-speed mode, its frame starting
//!   on the last control angle (the lost estimate's angle is no reference).
//!
//! - **With HFI** (salient motors, [`MotionConfig::hfi`]): the
//!   low-speed mode is closed loop on the [`crate::algorithms::hfi`] estimate instead of the current
//!   vector. On enable the current loops are held and the bridge applies the injection
//!   alone while HFI converges and tests the magnet's polarity (0.13 s, the mover does
//!   not move); the position estimate then starts from the HFI angle (zero at electrical
//!   angle 0, as without HFI). From then on the position loop, the speed loop (on the
//!   hold observer's speed, below) and `i_d = 0` run as in `Running`, on the
//!   fundamental current (the mean of two samples), with the injection added to the
//!   command; the q reference is slewed (a step reads as an HF response) and the
//!   friction learned while running is fed forward. At rest (reference speed zero) the
//!   speed loop gives way to a hold on a position, speed and load observer
//!   ([`crate::algorithms::load_observer`], at a quarter of HFI's bandwidth): thrust `M (k_v (v_ref -
//!   v_hat) + k_x (x_ref - x_hat))` plus the estimated load, a critically damped PD at
//!   half the observer's bandwidth. The observer's speed integrates the commanded thrust
//!   instead of differentiating HFI's noisy angle, and its load estimate takes the place
//!   of an integrator, which would wind up against static friction (a speed PI hunts by
//!   ±5 mm in stick-slip, and a 50 % load step deflects the mover 12.9 mm; the hold 2.8 mm).
//!   Moving, the running drive's loops (stiff ones disturb the hand-overs: lock is lost
//!   after reversals); the speed loop takes over from the hold's output and reads the
//!   observer's speed too, which a commanded acceleration does not make lag as it makes
//!   HFI's tracking-loop integrator lag (`docs/low-speed-operation.md`, "Moving on HFI").
//!   Moving or holding,
//!   the overload supervision of `Running` applies (thrust on the current limit, the
//!   speed off its command). Leaving the band, the
//!   estimator is seeded from the HFI angle; entering
//!   it, HFI is preset from the estimate.
//!
//! - **A speed drive** has the same low-speed mode, without moves or a position loop:
//!   its profile follows the speed reference ([`Profile::follow_speed`]) from the
//!   estimated position when the rate-limited reference falls below the threshold and
//!   stays there (its target inside the band, zero, or of the other sign), and the drive
//!   hands back to its speed loop as below once the reference is past the exit and the
//!   estimate tracks. Its thresholds and currents are [`MotionConfig::for_drive`]'s
//!   defaults, with the speed reference's acceleration limit.
//!
//! ## Transitions (bumpless)
//! Every change of the current reference is slewed at
//! [`MotionConfig::current_slew_a_per_s`].
//! - Running -> LowSpeed: the low-speed frame starts on the estimated angle (no jump in
//!   the control frame), the current reference keeps its value in that frame and slews
//!   to `(I, 0)`, and the decoupling feed-forward moves into the current controllers'
//!   integrators.
//! - LowSpeed -> Running: as the reference speed crosses the exit threshold the
//!   estimator is seeded ([`crate::estimator::Estimator::seed`]: observer in the steady
//!   state of the magnet flux at the expected mover angle, PLL on it, FLL on the
//!   reference speed). The drive stays in the low-speed mode until the estimate tracks
//!   and agrees with the reference speed within 20 % (from the current vector) or, on
//!   HFI, with HFI's speed on average within `HANDOVER_SPEED_AGREEMENT`, then hands over
//!   as from I/f start-up (current vector rotated into the estimated frame, d current
//!   ramped out, the speed loop's output continuing from the q current it takes over).
//!
//! ## Position estimate
//! `x_hat` is an unwrapped electrical angle, `tau / pi` metres per radian, counted in
//! binary-angle steps in an `i64` (no drift, no overflow within 2^31 turns): in
//! `Running` the estimated angle, in the low-speed mode the *expected mover angle*, the
//! vector's angle less the load angle `asin(F / (K_f |I|))` with `F` the profile's
//! `M a_ref` plus the learned load along the motion, filtered at `w_n` (the mover
//! answers with the spring's dynamics, not at once). Both transitions start from the
//! angle in use, so `x_hat` does not jump. The zero is the pole position the mover
//! aligns to when the drive is first enabled (electrical angle 0; later enables align to
//! the last angle): a non-salient motor has no other absolute reference.

#[cfg(doc)]
use super::MotionConfig;
use super::{Constants, Drive, DriveState};
use crate::algorithms::hfi::Hfi;
use crate::algorithms::load_observer::LoadObserver;
use crate::algorithms::motion::{MotionError, Move, Period, Profile, Setpoint};
use crate::algorithms::transforms::{AlphaBeta, Dq};
use crate::estimator::Estimate;
use crate::num::{Angle, Scalar, asin, decay, sin_cos};

/// Capacity of the drive's move queue.
pub const MOVE_QUEUE: usize = 8;

/// Steps of the binary [`Angle`] in one electrical turn (`2^32`).
const ANGLE_STEPS_PER_TURN: f32 = 4_294_967_296.0;

/// Leaving HFI for the back-EMF estimator, how far the just-seeded estimate's speed may
/// be from HFI's on average (share of the reference speed, dimensionless) for the
/// hand-over. The speed loop continues from HFI's thrust with the estimate as its measure,
/// so an estimate off by `e` of the speed loads `k_p e w` into the loop's integrator, a
/// thrust nobody asked for once the estimate settles on the mover: the speed overshoots
/// by about `e` of the profile's speed. Half the 10 % overshoot budget of a move, the rest
/// left to the speed loop's own (`docs/low-speed-operation.md`, "Moving on HFI").
pub(super) const HANDOVER_SPEED_AGREEMENT: f32 = 0.05;

/// Positioning state and constants (working units unless named in SI).
#[derive(Clone, Debug)]
pub(super) struct Positioning<T> {
    pub(super) profile: Profile<T, MOVE_QUEUE>,
    /// The control period and the speed loop's: the profile's steps.
    pub(super) control_period: Period<T>,
    pub(super) speed_loop_period: Period<T>,
    /// A speed drive's low-speed mode: the profile follows the speed reference
    /// ([`Profile::follow_speed`]) through the band, no moves, no position loop.
    pub(super) follows_speed: bool,
    /// [`Positioning::enter_m_per_s`] as an electrical speed (working units).
    pub(super) enter_omega: T,
    /// Enter the low-speed mode below this reference speed, m/s.
    pub(super) enter_m_per_s: f32,
    /// Leave it above this reference speed, m/s.
    pub(super) exit_m_per_s: f32,
    pub(super) low_speed_current: T,
    /// Vector amplitude at the band's edge (working units).
    pub(super) exit_current: T,
    pub(super) slew_step: T,
    /// Position-loop gain, 1/s.
    pub(super) position_gain: f32,
    /// That gain as the speed command (electrical, working units) per electrical turn of
    /// lead: `position_gain * 2 tau * speed_to_omega`.
    pub(super) position_gain_per_turn: T,
    /// The profile's speed limit (electrical, working units): the position loop's bound.
    pub(super) speed_limit: T,
    /// Thrust current per m/s^2 of reference acceleration (A s^2/m, working current).
    pub(super) accel_current_per_m_s2: f32,
    /// Low-speed frame: `theta_ls = anchor_angle + (pi / tau) (x_ref - anchor_x -
    /// anchor_pending)`, `anchor_angle` (electrical) the mover's angle where its estimated
    /// position was `anchor_x_m` (m).
    pub(super) anchor_angle: Angle,
    pub(super) anchor_x_m: f32,
    /// What the frame has still to take up of the reference's lead on the estimated
    /// position when the mode was entered (m): the running loops' tracking error then,
    /// worked off at the position loop's gain, so that the frame does not jump and the
    /// mover still ends on the reference.
    pub(super) anchor_pending_m: f32,
    /// The estimator has been seeded for the exit from the low-speed mode.
    pub(super) seeded: bool,
    /// `HANDOVER_SPEED_AGREEMENT` in working units (dimensionless).
    pub(super) exit_agreement: T,
    /// Control periods the hand-over from HFI lets the disagreement filter run from the
    /// estimate's first tracking period: the PLL's lock-filter time, over which the
    /// estimator declares its own lock.
    pub(super) exit_agreement_periods: u32,
    /// The estimate's speed less HFI's since the seed, low-passed at the PLL's lock-filter
    /// time (electrical, working units).
    pub(super) exit_disagreement: T,
    /// The rate of that filter per control period (dimensionless, <= 1).
    pub(super) exit_filter_rate: T,
    /// Rate of the speed-error filter per period (dimensionless, <= 1).
    pub(super) speed_filter_rate: f32,
    /// Filtered electrical speed error of the mover against the reference (rad/s, SI).
    pub(super) speed_error_rad_s: f32,
    /// Magnitude of the mover's electrical speed read from the q voltage, filtered as
    /// the speed error (rad/s, SI): the slip supervision's reading of a mover slipping
    /// pole after pole, whose signed reading averages out.
    pub(super) speed_reading_abs_rad_s: f32,
    /// The vector's retard behind the reference position in the last step (rad), and
    /// its rate (rad/s) filtered at the current loop's bandwidth: the speed at which the
    /// current loop turns the current with the frame, beyond the reference speed.
    pub(super) retard_rad: f32,
    pub(super) retard_rate_rad_s: f32,
    /// The current loop's bandwidth times the period (dimensionless, <= 1): that filter's
    /// rate per period.
    pub(super) current_loop_rate: f32,
    /// Thrust per working unit of thrust current (N): the load learned along the motion
    /// as a force, for the hold observer that starts from it.
    pub(super) newtons_per_unit_current: f32,
    /// Thrust current (working units) the axis needed beyond acceleration while running
    /// sensorless (friction and load, along the motion), filtered: the low-speed mode's
    /// load angle, and with HFI its feed-forward along the motion. Learned in the
    /// working type, from the commanded q current less the acceleration's feed-forward,
    /// so that learning it costs the fixed-point drive no conversion.
    pub(super) load_current: T,
    /// Rate of that filter per update (dimensionless, <= 1): it is updated once per
    /// speed-loop period, at 50 ms.
    pub(super) load_learning_rate: T,
    /// Settling dither: time at rest (s), angular frequency (rad/s), decay rate (1/s).
    pub(super) rest_time_s: f32,
    pub(super) dither_rad_s: f32,
    pub(super) dither_decay_per_s: f32,
    /// The speed loop's last output and the acceleration feed-forward as applied
    /// (slewed), thrust current (working units).
    pub(super) speed_loop_out: T,
    pub(super) accel_ff_applied: T,
    /// Running sensorless: the acceleration feed-forward of the last reference (thrust
    /// current, working units), which `accel_ff_applied` slews to.
    pub(super) accel_ff_target: T,
    /// With HFI in the low-speed mode: the last reference's speed (electrical, working
    /// units).
    pub(super) reference_omega: T,
    /// The low-speed mode's slip supervision: the speed reading beyond which a mover at
    /// rest is off the vector's spring (rad/s, SI: `w_n + w_ls`), and the time an
    /// alignment on enable is given to settle before the supervision binds (s: two of
    /// the spring's periods) with what is left of it.
    pub(super) slip_margin_rad_s: f32,
    pub(super) slip_settle_s: f32,
    pub(super) slip_guard_s: f32,
    /// Expected mover angle relative to the low-speed frame (rad), filtered, and the
    /// filter's rate per period (the spring's natural frequency times the period).
    pub(super) mover_offset_rad: f32,
    pub(super) mover_filter_rate: f32,
    /// The alignment on enable is complete (the profile may move).
    pub(super) aligned: bool,
    /// High-frequency injection (salient motors): the low-speed mode's estimator.
    pub(super) hfi: Option<Hfi<T>>,
    /// The hold observer's [`LoadObserver::speed_over_bandwidth_m`] to the working
    /// electrical speed: its bandwidth times the motor's rad/m, in working units of
    /// speed per m (0 without HFI).
    pub(super) observer_speed_to_omega: T,
    /// With HFI, the hold at rest is the thrust law running (the speed loop takes over
    /// from its output when the reference moves again).
    pub(super) holding: bool,
    /// With HFI: position, speed and load observer on the HFI position and the commanded
    /// thrust ([`crate::algorithms::load_observer`]); at rest the drive holds the reference with a
    /// PD law on its estimates and its load estimate fed forward.
    pub(super) hold_observer: Option<LoadObserver<T>>,
}

impl<T: Scalar> Positioning<T> {
    /// `true` once the reference at `sp` is fast enough to leave the low-speed mode:
    /// beyond the exit threshold, or, following a speed, at a target the band's
    /// threshold or faster (a target inside the hysteresis would otherwise keep the
    /// drive in the band).
    fn past_exit(&self, sp: &Setpoint) -> bool {
        let v = sp.speed_m_per_s.abs();
        v > self.exit_m_per_s
            || self.profile.speed_target().is_some_and(|t| t.abs() >= self.enter_m_per_s && v >= t.abs())
    }

    /// The position loop's speed command (electrical, working units): the setpoint's
    /// speed plus the gain times the setpoint's lead on the estimated position
    /// (`position_counts`, the control angle unwrapped in 2^-32 of a turn), within the
    /// profile's speed limit. A mover behind its reference (one that left HFI a few mm
    /// behind, or whose position estimate moved at a hand-over) catches up where the
    /// profile runs below the limit, on its deceleration, rather than past the axis's top
    /// speed while cruising.
    ///
    /// The lead is formed by [`Scalar::lead_turns`]: for the fixed-point types in the
    /// angle's integer counts, one soft-float product and a conversion on Cortex-M3; the
    /// gain per turn, `2 pi k_x / omega_base`, holds in Q8.24 for any base speed above
    /// 0.05 k_x, and the lead saturates at the type's range, beyond the limit.
    #[inline(never)]
    fn speed_command(&self, sp: &Setpoint, position_counts: i64, k: &Constants<T>) -> T {
        let correction =
            T::lead_turns(sp.position_m * k.turns_per_metre, position_counts, self.position_gain_per_turn);
        (Drive::electrical_speed(k, sp.speed_m_per_s) + correction)
            .clamp_to(-self.speed_limit, self.speed_limit)
    }
}

/// What HFI contributes to one step of the low-speed mode (working units).
#[derive(Clone, Copy, Debug)]
pub(super) struct HfiStep<T> {
    /// Voltage to add to the command, V.
    pub(super) inject: AlphaBeta<T>,
    /// The fundamental current for the current loops, A.
    pub(super) i_fundamental: AlphaBeta<T>,
    /// `false` while aligning (converging, polarity): the current loops are held and the
    /// bridge applies the injection alone.
    pub(super) ready: bool,
}

impl<T: Scalar> Drive<T> {
    /// A positioning drive's state (`None` on a speed drive, whose low-speed mode shares
    /// the type).
    fn stroke(&self) -> Option<&Positioning<T>> {
        self.positioning.as_ref().filter(|p| !p.follows_speed)
    }

    /// `true` for a positioning drive ([`DriveConfig::motion`](super::DriveConfig)).
    pub fn is_positioning(&self) -> bool {
        self.stroke().is_some()
    }

    /// Queues a move (positioning drives only: `Err(Unreachable)` on a speed drive).
    /// Targets are in the position estimate's frame (m, see [`Drive::position_m`]).
    pub fn push_move(&mut self, m: Move) -> Result<(), MotionError> {
        match &mut self.positioning {
            Some(p) if !p.follows_speed => p.profile.push(m),
            _ => Err(MotionError::Unreachable),
        }
    }

    /// The present reference of the motion profile (SI), for a positioning drive.
    pub fn setpoint(&self) -> Option<Setpoint> {
        self.stroke().map(|p| p.profile.setpoint())
    }

    /// Moves waiting in the queue, not counting the active one (`None` on a speed drive).
    pub fn moves_queued(&self) -> Option<usize> {
        self.stroke().map(|p| p.profile.queued())
    }

    /// `true` when a positioning drive has no move active or queued (its reference is at
    /// rest); `false` while it moves and on a speed drive.
    pub fn motion_idle(&self) -> bool {
        self.stroke().is_some_and(|p| p.profile.is_idle())
    }

    /// `true` for a speed drive (its profile follows the speed reference in the
    /// low-speed mode).
    pub(super) fn follows_speed(&self) -> bool {
        self.positioning.as_ref().is_some_and(|p| p.follows_speed)
    }

    /// A speed drive's speed target (m/s) for its profile in the low-speed mode.
    fn speed_target_m_per_s(&self) -> f32 {
        self.speed_from_omega(self.omega_target)
    }

    /// A speed drive whose rate-limited reference is slower than the low-speed threshold
    /// and stays there (its target inside the band, or zero, or of the other sign: a
    /// stop or a reversal) enters the low-speed mode, as a positioning drive does when
    /// its reference slows: the profile follows the speed reference from the estimated
    /// position, and the drive hands back to `Running` once the reference is fast again
    /// and the estimate tracks. A reference only passing the band's edge on its way up
    /// (the I/f start's hand-over speed below the threshold) does not. `None` (nothing
    /// changed) otherwise, and on a positioning drive.
    pub(super) fn speed_reference_low_speed(&mut self, estimate: &Estimate<T>) -> Option<(Angle, T)> {
        let p = self.positioning.as_ref().filter(|p| p.follows_speed)?;
        let (target, reference) = (self.omega_target, self.omega_ref);
        let stays = target.abs() < p.enter_omega || (target < T::ZERO) != (reference < T::ZERO);
        if !(stays && reference.abs() < p.enter_omega) {
            return None;
        }
        let (v, target) = (self.follow_speed_reference(), self.speed_target_m_per_s());
        let thrust = self.pi_speed.integral().to_f32();
        if let Some(p) = &mut self.positioning {
            // The load along the motion, for the low-speed mode's load angle and the
            // hand-over back: the speed integrator's thrust (a speed drive feeds nothing
            // forward) less the thrust of the ramp towards the target. Not with HFI,
            // whose own speed loop carries the load through the band (fed forward there,
            // an integrator fresh from a start put HFI's speed 60 % over its reference).
            let ramp = p.profile.limits().max_accel_m_per_s2 * p.accel_current_per_m_s2;
            let ramp = if target > v {
                ramp
            } else if target < v {
                -ramp
            } else {
                0.0
            };
            let along = if v < 0.0 { ramp - thrust } else { thrust - ramp };
            if along.is_finite() && p.hfi.is_none() {
                p.load_current = T::from_f32(along);
            }
        }
        Some(self.enter_low_speed(estimate.theta_e, estimate.omega_e, estimate.speed_m_per_s.to_f32()))
    }

    /// A speed drive's profile follows its speed reference from the estimated position
    /// at the reference's present speed, which it returns (m/s). Not inlined: one copy
    /// for its two callers (the ESC1 image's flash).
    #[inline(never)]
    pub(super) fn follow_speed_reference(&mut self) -> f32 {
        let v = self.speed_from_omega(self.omega_ref);
        let (x, target) = (self.position_m(), self.speed_target_m_per_s());
        if let Some(p) = &mut self.positioning {
            p.profile.follow_speed(x, v, target);
        }
        v
    }

    /// Estimated mover position, m: the unwrapped control angle times `tau / pi`, from
    /// the pole position the mover aligned to on enable (see the module docs).
    pub fn position_m(&self) -> f32 {
        // Through 32-bit integers (the same values): an i64 to f32 conversion is a library
        // call on Cortex-M.
        let counts = self.position_counts;
        f32::from_turns((counts >> 32) as i32, counts as u32, self.k.metres_per_turn)
    }

    /// The estimated mover position of [`Drive::position_m`] in the working type (m):
    /// [`Scalar::from_turns`] of the count, for the loops that run on it in every period.
    pub(super) fn position(&self) -> T {
        let counts = self.position_counts;
        T::from_turns((counts >> 32) as i32, counts as u32, self.k.metres_per_turn_working)
    }

    /// Counts the control angle's change into the position estimate.
    pub(super) fn track_position(&mut self, theta: Angle) {
        self.position_counts =
            self.position_counts.saturating_add(i64::from((theta - self.theta_previous).bits()));
        self.theta_previous = theta;
    }

    /// Drops the queued and active moves; the reference holds at the estimated position.
    pub(super) fn drop_moves(&mut self) {
        let x = self.position_m();
        if let Some(p) = &mut self.positioning {
            p.profile.reset(x);
        }
    }

    /// Enters the low-speed mode for the alignment on enable: vector at the last
    /// control angle (0 on the first enable), ramping up from zero; the profile holds
    /// until it is aligned, then runs the queued moves.
    pub(super) fn start_positioning(&mut self) {
        let x = self.position_m();
        if let Some(p) = &mut self.positioning {
            p.profile.hold_at(x);
            p.speed_error_rad_s = 0.0;
            p.speed_reading_abs_rad_s = 0.0;
            p.retard_rad = 0.0;
            p.retard_rate_rad_s = 0.0;
            p.mover_offset_rad = 0.0;
            p.slip_guard_s = p.slip_settle_s;
            p.anchor_angle = self.theta_previous;
            p.anchor_x_m = x;
            p.anchor_pending_m = 0.0;
            p.seeded = false;
            p.aligned = false;
            if let Some(h) = &mut p.hfi {
                // Angle and polarity found again (the mover may have moved while off).
                h.reset();
            }
        }
        self.i_dq_ref = Dq::default();
        self.state = DriveState::LowSpeed;
    }

    /// Low-speed mode: the current vector on the reference position; seeds the
    /// estimator and hands over once the reference is fast enough and the estimate
    /// tracks.
    pub(super) fn low_speed_references(&mut self, estimate: &Estimate<T>, i_ab: AlphaBeta<T>) -> (Angle, T) {
        let dt_s = self.k.dt_s;
        let speed_target = self.follows_speed().then(|| self.speed_target_m_per_s());
        let Some(p) = &mut self.positioning else {
            return (self.theta_previous, T::ZERO);
        };
        // Slew the current vector towards (I, 0) in the low-speed frame, I from I_ls at
        // rest to I_exit at the band's edge (see the module docs).
        let step = p.slew_step;
        let d = self.i_dq_ref.d;
        let speed_fraction = (p.profile.setpoint().speed_m_per_s.abs() / p.enter_m_per_s).min(1.0);
        let target = if p.aligned {
            p.low_speed_current - T::from_f32(speed_fraction) * (p.low_speed_current - p.exit_current)
        } else {
            p.low_speed_current
        };
        self.i_dq_ref.d = if d < target { (d + step).min(target) } else { (d - step).max(target) };
        let q = self.i_dq_ref.q;
        self.i_dq_ref.q = if q > T::ZERO { (q - step).max(T::ZERO) } else { (q + step).min(T::ZERO) };
        if !p.aligned {
            p.aligned = self.i_dq_ref.d == target && self.i_dq_ref.q == T::ZERO;
        }
        let i_ref = self.i_dq_ref;
        let amplitude = Scalar::sqrt(i_ref.d * i_ref.d + i_ref.q * i_ref.q);
        let amplitude_a = amplitude.to_f32() * self.k.base.current_a;
        if let Some(v) = speed_target {
            p.profile.set_speed_target(v);
        }
        let sp = if p.aligned { p.profile.step(&p.control_period) } else { p.profile.setpoint() };
        let omega_ref = Self::electrical_speed(&self.k, sp.speed_m_per_s);
        // The mover's speed from the q voltage of the last step: in the frame turning at
        // `w_frame`, u_q = Rs i_q + w_frame Ld i_d + w psi_f cos(delta); the inverter's
        // error lies along the current vector (d), so u_q is clean. The frame turns at the
        // reference speed less the retard's rate, and the current loop turns the current
        // with it at its own bandwidth: read at the reference speed alone, a change of the
        // retard would read as a speed of `Ld I / psi_f` times its rate and feed back into
        // the retard through the current loop (unstable where `Ld I` is several times
        // `psi_f`). The retard's rate is therefore filtered at the current loop's bandwidth,
        // the rate at which the loop's voltage follows it.
        let k = &self.k;
        let i = self.i_dq_measured;
        let omega_frame = omega_ref - T::from_f32(p.retard_rate_rad_s * k.inv_omega_base);
        let omega_mover = (self.u_dq_last.q - k.rs * i.q - omega_frame * k.ld * i.d) * k.inv_psi_f;
        let error_rad_s = (omega_mover - omega_ref).to_f32() * k.base.omega_rad_s;
        let mover_rad_s = omega_mover.to_f32() * k.base.omega_rad_s;
        if error_rad_s.is_finite() {
            p.speed_error_rad_s += p.speed_filter_rate * (error_rad_s - p.speed_error_rad_s);
            p.speed_reading_abs_rad_s +=
                p.speed_filter_rate * (libm::fabsf(mover_rad_s) - p.speed_reading_abs_rad_s);
        }
        // Slip: a mover off the vector's spring, pushed pole after pole by a load the
        // vector cannot hold while the position estimate, the vector's, follows the
        // reference. The q voltage's reading `w cos(delta)` (filtered above as the speed
        // error) shows it once the mover moves faster than the inverter's error reads as
        // (`w_ls`): moving, a reading against the reference's direction puts the mover
        // beyond 90 deg from the vector, past the spring's peak force (a held mover reads
        // along the motion); at rest, a reading beyond a held swing of a radian at `w_n`
        // is a mover running away. Not while an alignment on enable settles (a mover
        // found half a pole pitch off swings faster, up to `2 w_n`).
        if p.aligned {
            p.slip_guard_s = if p.slip_guard_s > dt_s { p.slip_guard_s - dt_s } else { 0.0 };
        }
        let omega_ref_rad_s = sp.speed_m_per_s * self.k.omega_per_speed;
        let reading = p.speed_error_rad_s + omega_ref_rad_s;
        let readable = p.enter_m_per_s * self.k.omega_per_speed;
        let slipping = if omega_ref_rad_s == 0.0 {
            libm::fabsf(reading) > p.slip_margin_rad_s
        } else {
            reading * omega_ref_rad_s < 0.0 && libm::fabsf(reading) > readable
        };
        // A mover slipping pole after pole reads `w cos(delta)` with delta turning: the
        // signed reading averages out, its magnitude (2/pi of `w` on average) does not.
        // A held mover reads at most the reference's speed plus its swing on the spring
        // and the inverter's error (`w_n + w_ls`). Not while the current loops have lost
        // control (the voltage on its limit with the current off its reference): the
        // reading then rests on a current the loops do not hold (a stuck sensor reads
        // as a runaway), and the current-control supervision names the fault.
        let running_away = self.current_error_count == 0
            && libm::fabsf(omega_ref_rad_s) + p.slip_margin_rad_s < p.speed_reading_abs_rad_s;
        if p.slip_guard_s == 0.0 && (slipping || running_away) {
            self.trip(crate::drive::Faults::OVERLOAD);
            return (self.theta_previous, T::ZERO);
        }
        // The vector trails the reference position by damping_s times the speed error:
        // a thrust against the mover's swing on the current vector's spring.
        let damping_s = k.vector_damping_s(amplitude);
        let retard = (damping_s * p.speed_error_rad_s).clamp(-0.5, 0.5);
        p.retard_rate_rad_s += p.current_loop_rate * ((retard - p.retard_rad) / dt_s - p.retard_rate_rad_s);
        p.retard_rad = retard;
        if p.anchor_pending_m != 0.0 {
            let rate = (p.position_gain * dt_s).min(1.0);
            p.anchor_pending_m -= rate * p.anchor_pending_m;
            // Taken up once below one step of the binary angle (it no longer turns the
            // frame): an exponential decay in f32 would otherwise never reach zero.
            if libm::fabsf(p.anchor_pending_m) * ANGLE_STEPS_PER_TURN < self.k.metres_per_turn {
                p.anchor_pending_m = 0.0;
            }
        }
        let lead_m = sp.position_m - p.anchor_x_m - p.anchor_pending_m;
        let theta = p.anchor_angle + (self.k.omega_per_speed * lead_m - retard).radians_to_angle();
        // Where the mover is expected: the current vector's angle less the load angle
        // asin(F / (K_f |I|)), F the profile's M a_ref plus the load learned while
        // running, along the motion (friction pushes back whichever way it moves).
        // At rest, where friction stopped the mover is not predictable (it may overshoot
        // the vector and stick): no load angle.
        let direction = if sp.speed_m_per_s == 0.0 { 0.0 } else { sp.speed_m_per_s.signum() };
        let force_a = (sp.accel_m_per_s2 * p.accel_current_per_m_s2 + direction * p.load_current.to_f32())
            * self.k.base.current_a;
        let load_angle = asin((force_a / amplitude_a.max(1e-3)).clamp(-1.0, 1.0));
        let vector = T::atan2(i_ref.q, i_ref.d);
        // The mover answers a change of the vector or of the force with the spring's
        // dynamics, not at once: the expected offset from the frame is filtered at the
        // spring's natural frequency (and the estimate never jumps on entry, where the
        // offset starts from zero).
        let offset = (vector - load_angle.radians_to_angle()).to_radians::<f32>();
        p.mover_offset_rad += p.mover_filter_rate * (offset - p.mover_offset_rad);
        let mover = theta + p.mover_offset_rad.radians_to_angle();
        self.low_speed_mover_angle = Some(mover);
        let alpha = Self::electrical_acceleration(&self.k, sp.accel_m_per_s2);
        self.estimator.set_commanded_acceleration(alpha);
        if !p.past_exit(&sp) {
            p.seeded = false;
            // Settling dither at rest: a decaying wobble of the vector that breaks the
            // mover away from where friction stopped it, so it comes to rest nearer
            // the vector.
            let at_rest = sp.speed_m_per_s == 0.0 && p.aligned;
            p.rest_time_s = if at_rest { p.rest_time_s + dt_s } else { 0.0 };
            // Amplitude: twice the load angle of the friction learned while running
            // (where friction holds the mover), decaying over a few of the spring's
            // periods; frequency 0.8 of the spring's natural frequency. Computed only
            // while it lasts (seven decay times, e^-7 of the start).
            let t = p.rest_time_s;
            let dither = if at_rest && t * p.dither_decay_per_s < 7.0 {
                let ratio = p.load_current.abs().to_f32() * self.k.base.current_a / amplitude_a.max(1e-3);
                let amp = (2.0 * asin(ratio.min(1.0))).min(0.2) * decay(t * p.dither_decay_per_s);
                amp * sin_cos(p.dither_rad_s * t).0
            } else {
                0.0
            };
            return (theta + dither.radians_to_angle(), omega_ref);
        }
        if !p.seeded {
            self.estimator.seed(mover, omega_ref, i_ab);
            p.seeded = true;
            return (theta, omega_ref);
        }
        let close = (estimate.omega_e - omega_ref).abs() < omega_ref.abs() * self.k.handover_tolerance;
        if estimate.tracking && close {
            self.hand_over_to_position_loop(theta, estimate);
            return (estimate.theta_e, estimate.omega_e);
        }
        (theta, omega_ref)
    }

    /// Leaves the low-speed mode for `Running` from the control frame at `theta`: the
    /// current loops move to the estimated frame ([`Drive::hand_over`]) and the speed
    /// loop, on the position loop's speed command (a positioning drive) or the speed
    /// reference (a speed drive) from now on, starts from the thrust the mover needs
    /// (below). A positioning drive takes the difference from the present q current up
    /// through its feed-forward's slew; a speed drive, which slews nothing, steps it at
    /// its speed loop's first update.
    fn hand_over_to_position_loop(&mut self, theta: Angle, estimate: &Estimate<T>) {
        self.hand_over(theta, estimate);
        let positioning = self.is_positioning();
        let error = if positioning { self.position_command() } else { self.omega_ref } - self.omega_filtered;
        let iq = self.i_dq_ref.q;
        let Some(p) = &mut self.positioning else {
            return;
        };
        let sp = p.profile.setpoint();
        let iq_ff = Self::accel_feed_forward(p, &sp);
        // What the speed loop starts from. Leaving HFI, the q current is the thrust HFI's
        // own speed loop found, in a frame that was the mover's: it continues from there.
        // Leaving the current vector, the q current in the estimated frame is `|I| sin e`,
        // `e` the vector's lead on the *estimate*, which may be 10-25 deg off the mover
        // at this instant: for a vector of several amperes that is amperes of thrust
        // nobody asked for once the estimate settles (docs/low-speed-operation.md,
        // "Positioning through zero speed"). It starts instead from the thrust the mover
        // is known to need beyond acceleration (the load learned along the motion).
        let start = if p.hfi.is_some() {
            iq - iq_ff
        } else if sp.speed_m_per_s < 0.0 {
            -p.load_current
        } else {
            p.load_current
        };
        if !positioning {
            // A speed drive: its speed loop on the speed reference, nothing fed forward.
            self.pi_speed.preset(start + iq_ff, error);
            return;
        }
        // The difference from the present q current is slewed out with the acceleration
        // feed-forward, so the current does not step.
        self.pi_speed.preset(start, error);
        p.speed_loop_out = start;
        p.accel_ff_applied = iq - start;
        p.accel_ff_target = iq_ff;
        self.state = DriveState::Running;
    }

    /// The position loop's speed command (electrical, working units) for the present
    /// setpoint.
    fn position_command(&self) -> T {
        let Some(p) = &self.positioning else {
            return T::ZERO;
        };
        p.speed_command(&p.profile.setpoint(), self.position_counts, &self.k)
    }

    /// The acceleration feed-forward (thrust current, working units) of the setpoint `sp`.
    fn accel_feed_forward(p: &Positioning<T>, sp: &Setpoint) -> T {
        T::from_f32(sp.accel_m_per_s2 * p.accel_current_per_m_s2)
    }

    /// The electrical speed (working units) of a mover speed `v_m_per_s` (m/s) on the
    /// drive of constants `k`.
    fn electrical_speed(k: &Constants<T>, v_m_per_s: f32) -> T {
        T::from_f32(v_m_per_s * k.speed_to_omega)
    }

    /// The electrical acceleration (working units of speed per working time) of a mover
    /// acceleration `a_m_per_s2` (m/s^2) on the drive of constants `k`.
    fn electrical_acceleration(k: &Constants<T>, a_m_per_s2: f32) -> T {
        T::from_f32(a_m_per_s2 * k.accel_to_alpha)
    }

    /// The motion profile at the speed loop's rate: in the period before the speed loop's
    /// (every period with no divider) it advances by the speed loop's period, and its
    /// speed, acceleration feed-forward and commanded acceleration are formed; `Some` with
    /// the new setpoint then, `None` in the other periods (`docs/cost-budget.md`,
    /// "Divided rates").
    fn advance_profile_if_due(&mut self) -> Option<Setpoint> {
        let n = self.k.speed_loop_divider;
        if !(self.speed_divider_count.saturating_add(2) == n || n == 1) {
            return None;
        }
        let p = self.positioning.as_mut()?;
        let sp = p.profile.step(&p.speed_loop_period);
        p.accel_ff_target = Self::accel_feed_forward(p, &sp);
        p.reference_omega = Self::electrical_speed(&self.k, sp.speed_m_per_s);
        let alpha = Self::electrical_acceleration(&self.k, sp.accel_m_per_s2);
        self.estimator.set_commanded_acceleration(alpha);
        Some(sp)
    }

    /// Into the low-speed mode on the control frame at `theta` turning at `omega`
    /// (electrical, working units; the mover at `speed_m_per_s`): the estimated angle as
    /// the reference slows, the last control angle after a lock loss. The frame does not
    /// jump (the current reference keeps its value and slews from there), the decoupling
    /// feed-forward moves into the integrators, the position estimate continues.
    pub(super) fn enter_low_speed(&mut self, theta: Angle, omega: T, speed_m_per_s: f32) -> (Angle, T) {
        let x_m = self.position_m();
        if let Some(p) = &mut self.positioning {
            let sp = p.profile.setpoint();
            // The frame starts on the mover (no jump) and, on a move, takes up the
            // reference's lead over the following periods: anchored on the reference
            // instead, the tracking error of this instant would stay in every position to
            // come. Following a speed reference, the position is no one's target.
            p.anchor_angle = theta;
            p.anchor_x_m = if p.follows_speed { sp.position_m } else { x_m };
            p.anchor_pending_m = sp.position_m - p.anchor_x_m;
            p.reference_omega = Self::electrical_speed(&self.k, sp.speed_m_per_s);
            p.seeded = false;
            p.aligned = true;
            p.speed_error_rad_s = 0.0;
            p.speed_reading_abs_rad_s = 0.0;
            p.retard_rad = 0.0;
            p.retard_rate_rad_s = 0.0;
            p.mover_offset_rad = 0.0;
        }
        let k = &self.k;
        let i = self.i_dq_ref;
        let ff_d = -omega * k.lq * i.q;
        let ff_q = omega * (k.ld * i.d + k.psi_f);
        let (int_d, int_q) = (self.pi_d.integral(), self.pi_q.integral());
        self.pi_d.preset(int_d + ff_d, T::ZERO);
        self.pi_q.preset(int_q + ff_q, T::ZERO);
        self.estimator.set_commanded_acceleration(T::ZERO);
        self.state = DriveState::LowSpeed;
        if let Some(h) = self.positioning.as_mut().and_then(|p| p.hfi.as_mut()) {
            // HFI takes over from the estimated angle and speed; the polarity is known.
            h.preset(theta, omega, true);
        }
        if let Some(p) = &mut self.positioning
            && p.hfi.is_some()
        {
            p.holding = false;
            // The hold's observer starts on the sensorless estimates and the load learned
            // along the motion.
            let load_n = p.load_current.to_f32() * p.newtons_per_unit_current * speed_m_per_s.signum();
            if let Some(o) = &mut p.hold_observer {
                o.preset(x_m, speed_m_per_s, load_n);
            }
        }
        (theta, omega)
    }

    /// Sensorless positioning: position loop on `x_hat` with the profile's speed and
    /// acceleration fed forward; enters the low-speed mode when the reference slows.
    ///
    /// The outer loops run at the speed loop's divided rate, spread over two periods so
    /// that no one period carries both (`docs/cost-budget.md`, "Divided rates"): the
    /// profile advances by `speed_loop_divider` periods in the period *before* the speed
    /// loop's, so the position loop, in the speed loop's period, reads the reference of
    /// its own instant, as it would with the profile stepped every period; the load is
    /// learned in the profile's period. Between, the acceleration feed-forward slews
    /// towards the last reference's, as every change of the current reference does.
    pub(super) fn positioning_references(&mut self, estimate: &Estimate<T>) -> Option<(Angle, T)> {
        if let Some(sp) = self.advance_profile_if_due() {
            let p = self.positioning.as_mut()?;
            if sp.speed_m_per_s.abs() < p.enter_m_per_s {
                return Some(self.enter_low_speed(
                    estimate.theta_e,
                    estimate.omega_e,
                    estimate.speed_m_per_s.to_f32(),
                ));
            }
            // Learn the thrust beyond acceleration (friction, load) along the motion, from
            // the thrust current the loops command (the measured one follows it within the
            // current loop's bandwidth, without its noise), once per speed-loop period.
            // The acceleration's thrust current is this reference's feed-forward, formed
            // above; all in the working type.
            if sp.speed_m_per_s != 0.0 {
                let beyond = self.i_dq_ref.q - p.accel_ff_target;
                let along = if sp.speed_m_per_s < 0.0 { -beyond } else { beyond };
                if along.is_valid() {
                    p.load_current = p.load_current + (along - p.load_current).mul_unit(p.load_learning_rate);
                }
            }
        }
        if self.speed_loop_due() {
            self.omega_ref = self.position_command();
            let out = self.pi_speed.update(self.omega_ref - self.omega_filtered);
            if let Some(p) = &mut self.positioning {
                p.speed_loop_out = out;
            }
        }
        if let Some(p) = &mut self.positioning {
            // The trapezoid's acceleration steps; its feed-forward is slewed like every
            // other change of the current reference (bounded jerk of the thrust).
            let step = p.slew_step;
            p.accel_ff_applied =
                p.accel_ff_applied + (p.accel_ff_target - p.accel_ff_applied).clamp_to(-step, step);
            self.i_dq_ref.q = p.speed_loop_out + p.accel_ff_applied;
        }
        None
    }
}

impl<T: Scalar> Drive<T> {
    /// The low-speed mode of a drive with HFI (`None` without): closed loop on the HFI
    /// angle. On enable, the current loops are held while HFI converges and tests the
    /// polarity with the mover at rest (no alignment move); then the position estimate
    /// starts from the HFI angle (the zero is electrical angle 0, as without HFI), and the
    /// position loop, the speed loop on the hold observer's speed and `i_d = 0` run as in
    /// `Running`.
    /// Leaving the band, the estimator is seeded from the HFI angle and the drive hands
    /// over to it as from the current vector.
    pub(super) fn hfi_low_speed(
        &mut self,
        estimate: &Estimate<T>,
        i_ab: AlphaBeta<T>,
    ) -> Option<(Angle, T, HfiStep<T>)> {
        let speed_target = self.follows_speed().then(|| self.speed_target_m_per_s());
        let p = self.positioning.as_mut()?;
        let h = p.hfi.as_mut()?;
        let hold = HfiStep { inject: AlphaBeta::default(), i_fundamental: i_ab, ready: false };
        let Ok(o) = h.step(i_ab) else {
            self.trip(crate::drive::Faults::ESTIMATOR);
            return Some((self.theta_previous, T::ZERO, hold));
        };
        let step =
            HfiStep { inject: o.u_inject_ab, i_fundamental: o.i_fundamental_ab, ready: o.polarity_known };
        if !o.polarity_known {
            // Aligning: nothing moves, the position estimate waits.
            p.aligned = false;
            self.i_dq_ref = Dq::default();
            self.pi_d.reset();
            self.pi_q.reset();
            self.pi_speed.reset();
            self.low_speed_mover_angle = Some(self.theta_previous);
            return Some((o.theta_e, T::ZERO, step));
        }
        let theta = o.theta_e;
        if !p.aligned {
            // The first step with the polarity known: the position estimate takes the HFI
            // angle (the shortest way from where it was), the profile holds there.
            p.aligned = true;
            p.seeded = false;
            p.speed_loop_out = T::ZERO;
            p.accel_ff_applied = T::ZERO;
            p.accel_ff_target = T::ZERO;
            p.reference_omega = T::ZERO;
            p.speed_error_rad_s = 0.0;
            p.speed_reading_abs_rad_s = 0.0;
            p.holding = false;
            self.pi_speed.reset();
            self.omega_filtered = T::ZERO;
            self.position_counts =
                self.position_counts.saturating_add(i64::from((theta - self.theta_previous).bits()));
            self.theta_previous = theta;
            let x = self.position_m();
            if let Some(p) = &mut self.positioning {
                p.profile.hold_at(x);
                if let Some(o) = &mut p.hold_observer {
                    o.preset(x, 0.0, 0.0);
                }
            }
        }
        // The position estimate in the working type, for the hold observer in every period
        // (in integers: no soft-float conversion on Cortex-M3); the position loop reads
        // the count itself (`Positioning::speed_command`).
        let x_hat = self.position();
        let Some(p) = &mut self.positioning else {
            return Some((theta, T::ZERO, step));
        };
        if let Some(v) = speed_target {
            p.profile.set_speed_target(v);
        }
        // The profile advances at the speed loop's rate, as running sensorless; between,
        // its reference holds.
        let advanced = self.advance_profile_if_due();
        let speed_loop_due = self.speed_loop_due();
        let Some(p) = &mut self.positioning else {
            return Some((theta, T::ZERO, step));
        };
        let sp = advanced.unwrap_or_else(|| p.profile.setpoint());
        // The position estimate: the HFI angle. (It is not low-passed at rest against its
        // noise: that lags a mover still moving with the reference at rest, 6.4 mm under
        // the 60 N load step of host/tests/hfi_drive.rs.)
        self.low_speed_mover_angle = Some(theta);
        let omega_ref = p.reference_omega;
        // Moving: the position and speed loops on the HFI estimate, as in `Running`. At rest:
        // the hold on the load observer (below). (A speed PI stiff enough to hold a load
        // step, used while moving too, disturbed the hand-overs: lock lost after reversals.)
        let at_rest = sp.speed_m_per_s == 0.0;
        let iq_ff = p.accel_ff_target;
        if speed_loop_due {
            // The position loop's speed command, for the speed loop (and the overload
            // supervision, which sees the command of the last update).
            if let Some(p) = &self.positioning {
                self.omega_ref = p.speed_command(&sp, self.position_counts, &self.k);
            }
        }
        let limit = self.k.current_limit;
        let iq_applied = self.i_dq_ref.q;
        let Some(p) = &mut self.positioning else {
            return Some((theta, T::ZERO, step));
        };
        // The observer sees the HFI position and the thrust commanded last period (the
        // current loops follow their reference within a few periods). At rest the thrust
        // current holds the reference: `M (k_v (v_ref - v_hat) + k_x (x_ref - x_hat))` plus
        // the estimated load, no integrator to wind up against static friction.
        // The observer runs every period; the hold's thrust law only at rest, where it
        // holds (moving, the speed loop has the thrust).
        // The speed loop's measure (and the speed filter's state at the hand-over to
        // `Running`): the observer's speed. Driven by the commanded thrust, it does not lag
        // a commanded acceleration as HFI's tracking-loop integrator does (the mover then
        // led its reference and overshot the profile's speed as it reached it); without an
        // observer, that integrator.
        let hold = match &mut p.hold_observer {
            Some(observer) => {
                observer.update(x_hat, iq_applied);
                self.omega_filtered = observer.speed_over_bandwidth_m() * p.observer_speed_to_omega;
                at_rest.then(|| {
                    observer.hold_thrust(&observer.target(sp.position_m, sp.speed_m_per_s, sp.accel_m_per_s2))
                })
            }
            None => {
                self.omega_filtered = o.omega_integral_e;
                None
            }
        };
        let holding = at_rest && hold.is_some();
        let error = self.omega_ref - self.omega_filtered;
        if holding {
            p.holding = true;
        } else if speed_loop_due {
            if p.holding {
                // Leaving the hold: the speed loop continues from the thrust that balances
                // the load the observer estimates. The hold's own thrust at this instant
                // also carries its correction of HFI's position noise (about ±1 A on the
                // salient test motor), which, continued, drove the mover up to 9 % over
                // the profile's speed at the end of the acceleration.
                let start = match &p.hold_observer {
                    Some(o) => o.load_thrust(),
                    None => p.speed_loop_out,
                };
                self.pi_speed.preset(start, error);
                p.holding = false;
            }
            p.speed_loop_out = self.pi_speed.update(error);
        }
        // Feed forward the profile's acceleration and, along the motion, the friction
        // learned while running sensorless (the speed loop's integrator then only takes
        // what is unexpected); at rest the hold's load estimate carries the friction.
        let iq_ff = if at_rest {
            iq_ff
        } else {
            iq_ff + if sp.speed_m_per_s < 0.0 { -p.load_current } else { p.load_current }
        };
        let slew = p.slew_step;
        p.accel_ff_applied = p.accel_ff_applied + (iq_ff - p.accel_ff_applied).clamp_to(-slew, slew);
        if let (true, Some(iq_hold)) = (holding, hold) {
            p.speed_loop_out = iq_hold - p.accel_ff_applied;
        }
        // Slewed: a step of the current reference makes the current loop step its voltage,
        // and a change of the fundamental's slope between two periods reads as an HF
        // response (`e` moves by `du / (2 L_q U_h D)`, 0.3 for 10 V on the salient motor,
        // which fed back through the speed loop); at `slew` per period it moves `e` by
        // at most `k_p slew / (2 L_q U_h D)` (0.04).
        let iq_target = (p.speed_loop_out + p.accel_ff_applied).clamp_to(-limit, limit);
        let iq = self.i_dq_ref.q;
        self.i_dq_ref.q = iq + (iq_target - iq).clamp_to(-slew, slew);
        let d = self.i_dq_ref.d;
        self.i_dq_ref.d = if d > T::ZERO { (d - slew).max(T::ZERO) } else { (d + slew).min(T::ZERO) };
        let omega = o.omega_e;
        // A load beyond the current limit pushes the mover off its reference, moving or
        // holding, with HFI reading where it goes: the overload supervision of `Running`.
        if self.supervise_overload() {
            return Some((theta, omega, step));
        }
        let Some(p) = &mut self.positioning else {
            return Some((theta, omega, step));
        };
        if !p.past_exit(&sp) {
            p.seeded = false;
            return Some((theta, omega, step));
        }
        if !p.seeded {
            self.estimator.seed(theta, omega_ref, i_ab);
            p.seeded = true;
            self.counter = 0;
            return Some((theta, omega, step));
        }
        // The hand-over waits until the just-seeded estimate agrees with HFI's speed (the
        // speed loop's measure, `omega_filtered`) on average: their difference, low-passed
        // from the first tracking period at the PLL's lock-filter time, within
        // `HANDOVER_SPEED_AGREEMENT` of the reference speed once the filter has run for
        // that time. The speed loop continues from the thrust with the estimate as its
        // measure, so an estimate off by a share of the speed loads that error into the
        // loop's integrator. The average, not each period's difference: the estimate's
        // speed carries its PLL's noise (±8 % at 0.4 m/s on the salient test motor), and
        // waiting for each period to agree kept a speed drive on HFI for seconds.
        // The state's period count (`counter`) counts the tracking periods since the seed.
        let difference = estimate.omega_e - self.omega_filtered;
        if !estimate.tracking {
            self.counter = 0;
        } else if self.counter == 0 {
            p.exit_disagreement = difference;
            self.counter = 1;
        } else {
            p.exit_disagreement =
                p.exit_disagreement + (difference - p.exit_disagreement).mul_unit(p.exit_filter_rate);
            self.counter = self.counter.saturating_add(1);
        }
        let agrees = p.exit_disagreement.abs() < omega_ref.abs().mul_unit(p.exit_agreement);
        if self.counter >= p.exit_agreement_periods && agrees {
            // As from the current vector: the frames differ by the two estimates'
            // disagreement only; the speed loop continues from the q current.
            self.hand_over_to_position_loop(theta, estimate);
            let step = HfiStep { inject: AlphaBeta::default(), ..step };
            return Some((estimate.theta_e, estimate.omega_e, step));
        }
        Some((theta, omega, step))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{DriveConfig, PAPER_AXIS_BUS_V};
    use crate::motor::MotorParams;
    use crate::num::units::Base;

    /// Puts the drive's position estimate at `x_m` (m): `2^32` counts per electrical turn
    /// of `2 tau`.
    fn place(drive: &mut Drive<f32>, x_m: f32) {
        drive.position_counts =
            (f64::from(x_m) / f64::from(drive.k.metres_per_turn) * 4_294_967_296.0) as i64;
    }

    /// The position loop's speed command against `v_ref + k_x (x_ref - x_hat)` and the
    /// axis's speed limit: behind its reference while the profile cruises at the top
    /// speed it asks for the top speed and no more; ahead, for less by the gain times the
    /// lead; on the deceleration, below the limit, it catches a lag up at the gain.
    #[test]
    fn the_position_loop_catches_up_within_the_axis_speed_limit() {
        let motor = MotorParams::paper();
        let config = DriveConfig::stroke_axis(&motor, PAPER_AXIS_BUS_V);
        let mut drive = Drive::<f32>::new(&motor, &config, &Base::SI).expect("stroke axis");
        drive.push_move(Move { target_m: 0.3, dwell_s: 0.0 }).expect("move within the stroke");
        let (v_max, gain) = {
            let p = drive.positioning.as_ref().expect("a positioning drive");
            (p.profile.limits().max_speed_m_per_s, p.position_gain)
        };
        let command_m_per_s = |drive: &Drive<f32>| drive.position_command() / drive.k.omega_per_speed;
        let step = |drive: &mut Drive<f32>| {
            let p = drive.positioning.as_mut().expect("a positioning drive");
            let sp = p.profile.step(&p.speed_loop_period);
            (sp, p.profile.setpoint())
        };
        // Cruising.
        let mut sp = Setpoint::default();
        for _ in 0..100_000 {
            sp = step(&mut drive).1;
            if sp.speed_m_per_s == v_max {
                break;
            }
        }
        assert_eq!(sp.speed_m_per_s, v_max, "the profile reaches its top speed");
        let lag_m = 0.005;
        place(&mut drive, sp.position_m - lag_m);
        let behind = command_m_per_s(&drive);
        assert!((behind - v_max).abs() <= 1e-6 * v_max, "behind: {behind} m/s, limit {v_max}");
        place(&mut drive, sp.position_m + lag_m);
        let ahead = command_m_per_s(&drive);
        let expected = v_max - gain * lag_m;
        assert!((ahead - expected).abs() <= 1e-3 * expected, "ahead: {ahead} m/s, expected {expected}");
        // Decelerating, a lag small enough to stay under the limit is caught up in full.
        let mut decelerating = None;
        for _ in 0..100_000 {
            let (sp, now) = step(&mut drive);
            if sp.accel_m_per_s2 < 0.0 && now.speed_m_per_s + gain * lag_m < 0.9 * v_max {
                decelerating = Some(now);
                break;
            }
        }
        let sp = decelerating.expect("the profile decelerates");
        place(&mut drive, sp.position_m - lag_m);
        let catching_up = command_m_per_s(&drive);
        let expected = sp.speed_m_per_s + gain * lag_m;
        assert!(
            (catching_up - expected).abs() <= 1e-3 * expected,
            "decelerating: {catching_up}, expected {expected}"
        );
    }
}
