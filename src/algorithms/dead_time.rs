//! The inverter's voltage error per leg (dead time and device drops) as a drive
//! compensates it: with the current at the switching edges, not its period mean.
//!
//! ## The dead time at the edges
//! Centre-aligned PWM turns leg `k`'s upper switch on over `[(1 - d_k) Ts/2,
//! (1 + d_k) Ts/2)`, every turn-on `Td` after its command. While both switches are off
//! the diodes choose the leg voltage by the current's sign *at that edge*:
//! - at the rising edge a current out of the leg (`i > 0`) holds the leg low for
//!   `Td`: the leg loses `Td Vdc`; a current into the leg takes it high at once;
//! - at the falling edge a current into the leg holds it high for `Td`: it gains
//!   `Td Vdc`; a current out of it takes it low at once.
//!
//! Over the period the leg's mean error is `-(Td / Ts) Vdc (H(i_rise) + H(i_fall) - 1)`
//! (`H` the unit step): `-(Td/Ts) Vdc` when both edges see a positive current,
//! `+(Td/Ts) Vdc` when both see a negative one, and *nothing* when the two edges see
//! opposite signs. The pattern is symmetric about the carrier peak, so the current's
//! ripple is odd about it: `i_rise = i_mid - delta_k`, `i_fall = i_mid + delta_k`, with
//! `i_mid` the current at the carrier peak (the period's mean to first order, what the
//! compensation reads) and
//!
//! ```text
//! delta_k = (1/L) integral_{rise}^{Ts/2} (v_kn - e_k) dt
//!         = (Ts / 2L) [ (max(0, u_k - u_j) + max(0, u_k - u_m)) / 3 - d_k u_k ]
//! ```
//!
//! where `u` are the phase references (the mean phase voltages, `e_k ~ u_k` over a
//! period), `j, m` the other two phases, and `d_k = 1/2 + (u_k + u_0) / Vdc` the duty
//! with the min-max zero sequence `u_0` of [`crate::algorithms::svpwm`]. Derivation: while leg `k`
//! is high, leg `j` is high over `min(d_k, d_j) Ts/2` of that half, so
//! `integral v_kn = Vdc (Ts/2) (2 d_k - min(d_k, d_j) - min(d_k, d_m)) / 3`, and
//! `d_k - min(d_k, d_j) = max(0, u_k - u_j) / Vdc` (the zero sequence cancels).
//! `delta_k >= 0` for every leg (the leg's own high interval pushes its current up).
//!
//! So within `|i_mid| < delta_k` the leg loses nothing, and the classic `sign(i)`
//! compensation adds the full `(Td/Ts) Vdc` there. The ripple is largest on the
//! middle leg, `(Ts / 6L) |u_min|` (about 0.07 A on the paper motor at 1.2 m/s, a
//! third of a 0.2 A light-load current amplitude, i.e. +-20 deg of every zero
//! crossing), and it is not symmetric about the crossing (its `e_k` term changes
//! sign there), so the misplaced compensation has a component across the current: in
//! `dcfo acquire`'s recordings a d-axis voltage error that grew with the speed to
//! degrees of angle bias, and a tenth of it with this model
//! (`docs/inverter-compensation.md`).
//!
//! ## Under injection
//! The bracket above takes the phase's mean voltage as met by its back-EMF (`e_k ~
//! u_k`): the current ripples about a level it keeps from one period to the next. A share
//! of the command that nothing meets (HFI's square wave, [`crate::algorithms::hfi`]: `U_h`
//! along d, one sign per period) ramps the current over the whole period instead, by
//! `u_inj,k / L_d` per second, so the edges move by `d_k u_inj,k Ts / 2 L_d` more, on
//! opposite sides of the carrier peak like the ripple: `delta_k` becomes `|delta_k +
//! d_k u_inj,k Ts / 2 L_d|` ([`InverterErrorModel::edge_ripple_injecting`]). On
//! `motors/salient.toml` the injection swings the d current by 25 % of the rated peak
//! each period, across zero in every phase whose fundamental is smaller: the inverter
//! then loses little, where signs taken from the fundamental alone add the whole
//! `(Td/Ts) Vdc` (5.7 V on that motor's 283 V bus). The back-EMF observer, told the
//! compensated command, would see that error against a back-EMF of 7.5 V at 0.4 m/s:
//! leaving the low-speed mode its flux estimate half the flux off, and the hand-over to
//! the sensorless loop going wrong. With the ramp modelled it is as accurate as on an
//! ideal inverter (`host/tests/speed_reversal.rs`).
//!
//! ## The compensation
//! Per leg, `(Td/Ts) Vdc (s(i - delta) + s(i + delta)) / 2 + V_drop s_drop(i)`, with
//! `s(x) = sat(x / band)` the smoothed sign of
//! [`DeadTimeCompensation::current_band_a`] and the
//! drop's sign linear over `max(band, delta)`: the current spends a share
//! `(1 + i / delta) / 2` of the period positive when the ripple spans zero.
//! A leg whose current lies beyond `delta + band` on either side (almost every sample
//! of a loaded drive) takes the whole `(Td/Ts) Vdc + V_drop` with its sign and forms no
//! product; below the fade's start (see below) the ripple is not formed at all. On the
//! Cortex-M3 in Q8.24 the stage costs about half of what forming every sign costs.
//!
//! ## Where the formula holds
//! The formula leaves out the dead time's own shift of the edges (`Td` after every
//! turn-on), which is small only while the active vectors are long against it, i.e.
//! while the duty spread `d_max - d_min` is many `Td / Ts`. Across the current (what
//! turns the flux estimate, `dU_d / (w psi_f)`) the edge model beats `sign(i)` from about
//! 4 dead times of spread on. Along the current, at light load and a small spread, the
//! edge model's error *falls* as the current rises: an inverter that seems to lose less
//! the more current it carries, a negative incremental resistance in the current loop,
//! which in the closed-loop drive made the speed loop hunt through zero thrust current.
//! Correcting the edges for the dead time's delay halved that error but not its slope.
//! So the ripple fades in with the spread from [`RIPPLE_FROM_DEAD_TIMES`] (6) to that
//! plus [`RIPPLE_FADE_DEAD_TIMES`] (3) dead times: the spread is `sqrt(3) |u| / Vdc` in
//! the linear range, so on the paper motor at light load from 0.65 to 0.95 m/s, and on
//! another motor wherever its voltage takes it. The measurements behind the thresholds
//! are in `docs/inverter-compensation.md`.
#![forbid(unsafe_code)]

use crate::algorithms::svpwm::DcBus;
use crate::algorithms::transforms::{Abc, AlphaBeta, clarke, inverse_clarke};
use crate::motor::MotorParams;
use crate::num::units::Base;
use crate::num::{Scalar, sqrt_rounded};

/// Compensation of the inverter's dead time and device drops, added to the voltage
/// command per phase as `(dead_time / Ts * Vdc + device_drop) * sign(i)`
/// (`docs/method.md` §8, `docs/inverter-compensation.md`), the sign smoothed over `current_band_a` and, where the duties spread far enough,
/// taken at the switching edges through the PWM ripple (the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeadTimeCompensation {
    /// Effective dead time, s (>= 0).
    pub dead_time_s: f32,
    /// Average device voltage drop, V (>= 0).
    pub device_drop_v: f32,
    /// Current over which the sign changes linearly from -1 to 1, A (> 0).
    pub current_band_a: f32,
}

/// The inverter-error model a drive compensates, in working units (see the module
/// docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverterErrorModel<T> {
    /// `Td / Ts` (dimensionless).
    pub dead_time_ratio: T,
    /// Device drop, V (working units).
    pub device_drop: T,
    /// [`DeadTimeCompensation::current_band_a`], A (working units): beyond it the sign is
    /// whole, with no product formed.
    pub band: T,
    /// `sqrt(1 / band)`, band in A (working units): applied twice, so that a narrow band
    /// stays representable in fixed point.
    pub inv_band_sqrt: T,
    /// `Ts / (2 L)`, A per V (working units): the edge ripple per volt of the bracket in
    /// the module docs.
    pub ripple_per_volt: T,
    /// `Ts / (2 L_d)`, A per V (working units): the edge offset per volt of an injected
    /// voltage along d (module docs, "Under injection").
    pub injection_ripple_per_volt: T,
    /// Duty spread (dimensionless) below which the ripple is left out:
    /// [`RIPPLE_FROM_DEAD_TIMES`] times `Td / Ts`.
    pub fade_from: T,
    /// Rate (per unit of duty spread) at which the ripple fades in above `fade_from`:
    /// `1 / (`[`RIPPLE_FADE_DEAD_TIMES`]` Td / Ts)`, saturated where that exceeds the
    /// range (a negligible dead time: the formula holds from small spreads on).
    pub fade_rate: T,
}

/// Duty spread `d_max - d_min`, in dead times `Td / Ts`, below which the edge ripple is
/// left out of the compensation (module docs, "Where the formula holds"): 3.
pub const RIPPLE_FROM_DEAD_TIMES: f32 = 6.0;

/// Duty spread, in dead times, over which the edge ripple fades in above
/// [`RIPPLE_FROM_DEAD_TIMES`]: 3 (in full from 6 on).
pub const RIPPLE_FADE_DEAD_TIMES: f32 = 3.0;

impl<T: Scalar> InverterErrorModel<T> {
    /// The model of the compensation `c` for a PWM period of `period_s` (s) on
    /// `motor` (the ripple inductance the mean of `Ld` and `Lq`: the ripple's vector
    /// turns with the switching state, not with the mover), in the working units of
    /// `base`. Fixed point: check that `1 / band` and `Ts / 2L` are representable first
    /// (the drive's configuration does).
    pub fn for_drive(c: &DeadTimeCompensation, period_s: f32, motor: &MotorParams, base: &Base) -> Self {
        let ratio = c.dead_time_s / period_s;
        let fade_rate = if ratio > 0.0 { 1.0 / (RIPPLE_FADE_DEAD_TIMES * ratio) } else { 1e6 };
        InverterErrorModel {
            fade_from: T::from_f32(RIPPLE_FROM_DEAD_TIMES * ratio),
            fade_rate: T::from_f32(fade_rate),
            dead_time_ratio: T::from_f32(ratio),
            device_drop: base.voltage(c.device_drop_v),
            band: base.current(c.current_band_a),
            inv_band_sqrt: T::from_f32(sqrt_rounded(base.current_a / c.current_band_a)),
            ripple_per_volt: T::from_f32(Self::ripple_per_volt_si(period_s, motor) * base.impedance_ohm()),
            injection_ripple_per_volt: T::from_f32(
                Self::injection_ripple_per_volt_si(period_s, motor) * base.impedance_ohm(),
            ),
        }
    }

    /// `Ts / 2L`, A/V (SI) for a PWM period of `period_s` (s) on `motor`.
    pub fn ripple_per_volt_si(period_s: f32, motor: &MotorParams) -> f32 {
        period_s / (motor.ld_h + motor.lq_h)
    }

    /// `Ts / 2 L_d`, A/V (SI) for a PWM period of `period_s` (s) on `motor`: the
    /// edge offset per volt of an injection along d (module docs, "Under injection").
    pub fn injection_ripple_per_volt_si(period_s: f32, motor: &MotorParams) -> f32 {
        0.5 * period_s / motor.ld_h
    }

    /// The per-leg edge ripple `delta_k` (A, working units, >= 0) of the phase
    /// references `u_ab` (V) on `bus`, module docs.
    pub fn edge_ripple(&self, u_ab: AlphaBeta<T>, bus: &DcBus<T>) -> Abc<T> {
        self.edge_ripple_injecting(u_ab, None, bus)
    }

    /// [`Self::edge_ripple`] of the command `u_ab` (V) with `inject` (V) of it not met by
    /// any back-EMF (an HF injection): its ramp over the period offsets the edges by
    /// `d_k u_inj,k Ts / 2 L_d` (module docs, "Under injection").
    pub fn edge_ripple_injecting(
        &self,
        u_ab: AlphaBeta<T>,
        inject: Option<AlphaBeta<T>>,
        bus: &DcBus<T>,
    ) -> Abc<T> {
        let inv_vdc = bus.inv_voltage();
        let u = inverse_clarke(u_ab);
        let hi = u.a.max(u.b).max(u.c);
        let lo = u.a.min(u.b).min(u.c);
        // Factors of magnitude at most one (halves, thirds, the fade weight, a duty)
        // are taken with `mul_unit`: the product cannot leave the range.
        let u0 = (-(hi + lo)).mul_unit(T::HALF);
        // Faded in with the duty spread (module docs, "Where the formula holds").
        let spread = (hi - lo) * inv_vdc;
        let weight = ((spread - self.fade_from) * self.fade_rate).clamp_to(T::ZERO, T::ONE);
        // Below the fade (every low-speed step): no ripple, and nothing to form.
        if weight <= T::ZERO && inject.is_none() {
            return Abc::default();
        }
        let gain = self.ripple_per_volt.mul_unit(weight);
        // (delta_k, d_k)
        let leg = |uk: T, uj: T, um: T| {
            let d = (T::HALF + (uk + u0) * inv_vdc).clamp_to(T::ZERO, T::ONE);
            let above = (uk - uj).max(T::ZERO) + (uk - um).max(T::ZERO);
            ((gain * (above.mul_unit(T::ONE_THIRD) - uk.mul_unit(d))).max(T::ZERO), d)
        };
        let ((ra, da), (rb, db), (rc, dc)) = (leg(u.a, u.b, u.c), leg(u.b, u.c, u.a), leg(u.c, u.a, u.b));
        let Some(inject) = inject else { return Abc { a: ra, b: rb, c: rc } };
        let v = inverse_clarke(inject);
        let g = self.injection_ripple_per_volt;
        let ramp = |rk: T, vk: T, dk: T| (rk + g * vk.mul_unit(dk)).abs();
        Abc { a: ramp(ra, v.a, da), b: ramp(rb, v.b, db), c: ramp(rc, v.c, dc) }
    }

    /// The compensation voltage (V, alpha-beta, working units) to add to the command
    /// `u_ab` (V) on `bus` for the phase currents `i` (A) at the middle of the period it
    /// is applied in (module docs).
    pub fn compensation(&self, u_ab: AlphaBeta<T>, bus: &DcBus<T>, i: Abc<T>) -> AlphaBeta<T> {
        self.compensation_injecting(u_ab, None, bus, i)
    }

    /// [`Self::compensation`] of a command `u_ab` (V) carrying an injection `inject` (V),
    /// a share of it no back-EMF meets (module docs, "Under injection"). Inlined: the
    /// drive calls it once, and out of line its images grew by about 500 B.
    #[inline(always)]
    pub fn compensation_injecting(
        &self,
        u_ab: AlphaBeta<T>,
        inject: Option<AlphaBeta<T>>,
        bus: &DcBus<T>,
        i: Abc<T>,
    ) -> AlphaBeta<T> {
        let delta = self.edge_ripple_injecting(u_ab, inject, bus);
        let dead = bus.voltage() * self.dead_time_ratio;
        let (band, inv) = (self.band, self.inv_band_sqrt);
        let sign = |x: T| (x * inv * inv).clamp_to(-T::ONE, T::ONE);
        let whole = dead + self.device_drop;
        let leg = |ik: T, dk: T| {
            // Beyond the band on both edges (most samples): every sign whole, no product.
            if ik - dk >= band {
                return whole;
            }
            if ik + dk <= -band {
                return -whole;
            }
            let dead_time = (dead * (sign(ik - dk) + sign(ik + dk))).mul_unit(T::HALF);
            // The drop's sign, linear over the wider of the band and the ripple: `ik / dk`
            // within the ripple, whole beyond it (`unit_ratio` limits the share: in fixed
            // point the quotient of a large current over a small ripple would not be
            // representable, and is not formed).
            let drop_sign = if dk > band { ik.unit_ratio(dk) } else { sign(ik) };
            // |drop_sign| <= 1.
            dead_time + self.device_drop.mul_unit(drop_sign)
        };
        clarke(Abc { a: leg(i.a, delta.a), b: leg(i.b, delta.b), c: leg(i.c, delta.c) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::Q24;

    /// The paper motor's drive: 10 kHz, L = 8.5 mH, 2 us, 0.95 V, 0.01 A; the ripple in
    /// full at every spread.
    fn model() -> InverterErrorModel<f64> {
        InverterErrorModel { fade_from: 0.0, fade_rate: 1e6, ..paper() }
    }

    fn paper() -> InverterErrorModel<f64> {
        InverterErrorModel::for_drive(&paper_inverter(), 1e-4, &MotorParams::paper(), &Base::SI)
    }

    /// The paper motor's inverter: 2 us dead time, 0.95 V drop, 0.01 A sign band.
    fn paper_inverter() -> DeadTimeCompensation {
        DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 }
    }

    /// [`model`] in Q8.24 on the paper motor's base (returned with it): the ripple in
    /// full from zero spread.
    fn q24_model() -> (Base, InverterErrorModel<Q24>) {
        let motor = MotorParams::paper();
        let base = Base::for_motor(&motor);
        let q = InverterErrorModel {
            fade_from: Q24::ZERO,
            ..InverterErrorModel::for_drive(&paper_inverter(), 1e-4, &motor, &base)
        };
        (base, q)
    }

    /// Leg currents `i` (A) in `base`'s Q8.24 working units.
    fn q24_currents(base: &Base, i: Abc<f64>) -> Abc<Q24> {
        Abc { a: base.current(i.a as f32), b: base.current(i.b as f32), c: base.current(i.c as f32) }
    }

    /// Under an injection (a share of the command that no back-EMF meets, here along the
    /// d axis of a salient motor), the current at each edge from the switching pattern,
    /// integrated finely with the injection ramping the current through `L_d` and the
    /// PWM ripple through the mean inductance, against the closed form: both edges lie
    /// `delta_k` from the carrier peak's current, on opposite sides.
    #[test]
    fn an_injection_ramps_the_edges_as_the_switching_pattern_does() {
        let motor = MotorParams { ld_h: 6e-3, lq_h: 9e-3, ..MotorParams::paper() };
        let ts = 1e-4;
        let c = DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 };
        let m = InverterErrorModel::<f64> {
            fade_from: 0.0,
            fade_rate: 1e6,
            ..InverterErrorModel::for_drive(&c, ts as f32, &motor, &Base::SI)
        };
        let vdc = 283.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let (l_mean, l_d) = (f64::from(motor.ld_h + motor.lq_h) / 2.0, f64::from(motor.ld_h));
        // (fundamental |u|, its angle, injection along d at angle theta_d, +-U_h)
        for &(mag, ang, theta_d, u_h) in
            &[(8.0, 1.9, 0.3, 63.6), (8.0, 1.9, 0.3, -63.6), (30.0, 4.0, 2.4, 40.0), (2.0, 5.5, 5.1, -63.6)]
        {
            let inject = AlphaBeta::new(u_h * f64::cos(theta_d), u_h * f64::sin(theta_d));
            let u_ab = AlphaBeta::new(mag * f64::cos(ang) + inject.alpha, mag * f64::sin(ang) + inject.beta);
            let (u, v) = (inverse_clarke(u_ab), inverse_clarke(inject));
            let hi = u.a.max(u.b).max(u.c);
            let lo = u.a.min(u.b).min(u.c);
            let u0 = -(hi + lo) / 2.0;
            let d = [0.5 + (u.a + u0) / vdc, 0.5 + (u.b + u0) / vdc, 0.5 + (u.c + u0) / vdc];
            let (mean, injected) = ([u.a, u.b, u.c], [v.a, v.b, v.c]);
            let delta = m.edge_ripple_injecting(u_ab, Some(inject), &bus);
            for (k, want) in [delta.a, delta.b, delta.c].into_iter().enumerate() {
                // The current from the carrier peak to time t: the PWM ripple `(v_kn -
                // u_k) / L` plus the injection's ramp `u_inj,k / L_d`.
                let current = |t: f64| {
                    let n = 100_000;
                    let h = (t - ts / 2.0) / n as f64;
                    let mut sum = 0.0;
                    for j in 0..n {
                        let t = ts / 2.0 + (j as f64 + 0.5) * h;
                        let high = |x: f64| if (t - ts / 2.0).abs() <= x * ts / 2.0 { vdc } else { 0.0 };
                        let vk = [high(d[0]), high(d[1]), high(d[2])];
                        let vn = (vk[0] + vk[1] + vk[2]) / 3.0;
                        sum += ((vk[k] - vn - mean[k]) / l_mean + injected[k] / l_d) * h;
                    }
                    sum
                };
                let rise = current((1.0 - d[k]) * ts / 2.0);
                let fall = current((1.0 + d[k]) * ts / 2.0);
                for (edge, got) in [("rising", -rise), ("falling", fall)] {
                    assert!(
                        (got.abs() - want).abs() < 1e-6 + 1e-4 * want.abs(),
                        "|u| {mag} ang {ang} U_h {u_h} leg {k} {edge} edge: {got} vs {want}"
                    );
                }
                assert!((rise + fall).abs() < 1e-6, "leg {k}: the edges are not symmetric ({rise}, {fall})");
            }
        }
    }

    /// The leg's current over one period from the switching pattern itself (phase
    /// voltage `v_kn` of the three legs' states, minus the mean), integrated finely:
    /// the ripple at the leg's rising edge, against the closed form.
    #[test]
    fn edge_ripple_matches_the_switching_pattern() {
        let m = model();
        let vdc = 311.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let ts = 1e-4;
        let l = 8.5e-3;
        for &(mag, ang) in &[(40.0, 0.3), (40.0, 1.9), (120.0, 4.0), (10.0, 5.5), (170.0, 2.6)] {
            let u_ab = AlphaBeta::new(mag * f64::cos(ang), mag * f64::sin(ang));
            let u = inverse_clarke(u_ab);
            let hi = u.a.max(u.b).max(u.c);
            let lo = u.a.min(u.b).min(u.c);
            let u0 = -(hi + lo) / 2.0;
            let d = [0.5 + (u.a + u0) / vdc, 0.5 + (u.b + u0) / vdc, 0.5 + (u.c + u0) / vdc];
            let mean = [u.a, u.b, u.c];
            let delta = m.edge_ripple(u_ab, &bus);
            for (k, want) in [delta.a, delta.b, delta.c].into_iter().enumerate() {
                // Integrate (v_kn - u_k) / L from the rising edge to the carrier peak.
                let n = 200_000;
                let t_rise = (1.0 - d[k]) * ts / 2.0;
                let h = (ts / 2.0 - t_rise) / n as f64;
                let mut sum = 0.0;
                for j in 0..n {
                    let t = t_rise + (j as f64 + 0.5) * h;
                    let high = |x: f64| if t >= (1.0 - x) * ts / 2.0 { vdc } else { 0.0 };
                    let v = [high(d[0]), high(d[1]), high(d[2])];
                    let vn = (v[0] + v[1] + v[2]) / 3.0;
                    sum += (v[k] - vn - mean[k]) * h;
                }
                let got = sum / l;
                assert!(
                    (got - want).abs() < 1e-6 + 1e-4 * want.abs(),
                    "|u| {mag} ang {ang} leg {k}: {got} vs {want}"
                );
                assert!(want >= 0.0);
            }
        }
    }

    /// Far from zero current the compensation is the classic `(Td/Ts Vdc + drop) sign(i)`;
    /// inside the ripple the dead time's part vanishes.
    #[test]
    fn classic_far_from_zero_and_nothing_inside_the_ripple() {
        let m = model();
        let vdc = 311.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let u_ab = AlphaBeta::new(0.0, 0.0);
        // Zero voltage: each leg at d = 1/2 with the others, delta = -(Ts/2L) d u = 0.
        let delta = m.edge_ripple(u_ab, &bus);
        assert!(delta.a.abs() < 1e-12 && delta.b.abs() < 1e-12);
        let i = Abc { a: 1.0, b: -0.5, c: -0.5 };
        let c = m.compensation(u_ab, &bus, i);
        let amp = 0.02 * vdc + 0.95;
        let want = clarke(Abc { a: amp, b: -amp, c: -amp });
        // (The model's constants are built in f32: 2 us / 100 us to within 1e-7.)
        assert!(
            (c.alpha - want.alpha).abs() < 1e-5 && (c.beta - want.beta).abs() < 1e-5,
            "{c:?} vs {want:?}"
        );
        // 40 V along alpha: leg a the top leg, b and c below; a current well inside
        // each leg's ripple gets only the drop's linear part.
        let u_ab = AlphaBeta::new(40.0, 0.0);
        let delta = m.edge_ripple(u_ab, &bus);
        // Leg b is the bottom leg: delta = -(Ts/2L) d_b u_b, d_b = 1/2 + (-20 - 10)/311.
        let want_b = 1e-4 / (2.0 * 8.5e-3) * (0.5 - 30.0 / vdc) * 20.0;
        assert!((delta.b - want_b).abs() < 1e-6 * want_b && delta.b > 4.0 * 0.01, "{delta:?}");
        let small = Abc { a: 0.0, b: 0.1 * delta.b, c: -0.1 * delta.b };
        let c = m.compensation(u_ab, &bus, small);
        let legs = inverse_clarke(c);
        // The drop only, linear over the ripple: 0.95 V x i / delta (f32 constants).
        assert!((legs.b - 0.95 * 0.1).abs() < 1e-6 && legs.a.abs() < 1e-9, "{legs:?}");
    }

    /// A current far beyond a leg's ripple takes the drop's whole sign in fixed point as
    /// in floating point: the quotient of the current over the ripple, 200 here, is beyond
    /// Q8.24's range, and a division that gave up there took the drop out altogether.
    #[test]
    fn a_large_current_takes_the_whole_drop_in_fixed_point_too() {
        let (base, q) = q24_model();
        let si = model();
        let vdc = 311.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let u_ab = AlphaBeta::new(40.0, 0.0);
        let delta_b = si.edge_ripple(u_ab, &bus).b;
        assert!(delta_b > 4.0 * 0.01, "leg b's ripple {delta_b} A is above the band");
        let i = Abc { a: -100.0 * delta_b, b: 200.0 * delta_b, c: -100.0 * delta_b };
        let want = inverse_clarke(si.compensation(u_ab, &bus, i));
        let to_q = |v: f64| base.voltage::<Q24>(v as f32);
        let i_q = q24_currents(&base, i);
        let q_bus = DcBus::new(to_q(vdc)).expect("a valid bus");
        let got =
            inverse_clarke(q.compensation(AlphaBeta::new(to_q(u_ab.alpha), to_q(u_ab.beta)), &q_bus, i_q));
        let volts = |x: Q24| f64::from(base.to_volts(x));
        for (g, w) in [(got.a, want.a), (got.b, want.b), (got.c, want.c)] {
            assert!((volts(g) - w).abs() < 0.01, "leg {} V against {w} V", volts(g));
        }
    }

    /// Where a leg's current crosses `delta + band` the compensation switches from the
    /// smoothed signs to the whole sign without a step, in floating and fixed point: the
    /// two sides of the switch within the smoothed sign's own change over the gap.
    #[test]
    fn the_whole_sign_beyond_the_band_meets_the_smoothed_one() {
        let (base, q) = q24_model();
        let si = model();
        let vdc = 311.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let q_bus = DcBus::new(base.voltage::<Q24>(vdc as f32)).expect("a valid bus");
        let u_ab = AlphaBeta::new(40.0, 0.0);
        let q_u = AlphaBeta::new(base.voltage::<Q24>(40.0), Q24::ZERO);
        let delta_b = si.edge_ripple(u_ab, &bus).b;
        let amp = 0.02 * vdc + 0.95;
        // Leg b's current just inside and just beyond the switch, either sign; legs a
        // and c far beyond the band, so that only leg b is near it.
        for sign in [1.0, -1.0] {
            for gap in [-1e-4, 1e-4] {
                let i_b = sign * (delta_b + 0.01 + gap);
                let i = Abc { a: -sign * 10.0, b: i_b, c: sign * 10.0 };
                let leg_b = |u: AlphaBeta<f64>| inverse_clarke(u).b;
                let got = leg_b(si.compensation(u_ab, &bus, i));
                // Every leg's whole sign, through the alpha-beta frame (which drops the
                // zero sequence) as the compensation is.
                let whole = leg_b(clarke(Abc { a: -sign * amp, b: sign * amp, c: sign * amp }));
                // s(x) = sat(x / band) changes by at most |gap| / band over the gap, on
                // the dead time's half of the leg and on the drop's (whole beyond the
                // ripple): (Td/Ts Vdc / 2 + 0) |gap| / band.
                let allowed = 0.5 * 0.02 * vdc * 1e-4 / 0.01 + 1e-9;
                assert!((got - whole).abs() <= allowed, "f64 gap {gap}: {got} vs {whole}");
                let i_q = q24_currents(&base, i);
                let got_q = f64::from(base.to_volts(inverse_clarke(q.compensation(q_u, &q_bus, i_q)).b));
                assert!((got_q - whole).abs() <= allowed + 1e-3, "Q8.24 gap {gap}: {got_q} vs {whole}");
            }
        }
    }

    /// The drive's model leaves the ripple out below RIPPLE_FROM_DEAD_TIMES dead times of
    /// duty spread, takes it in full from RIPPLE_FADE_DEAD_TIMES more, and in between
    /// in proportion.
    #[test]
    fn ripple_fades_in_with_the_duty_spread() {
        let (full, drive) = (model(), paper());
        let vdc = 311.0;
        let bus = DcBus::new(vdc).expect("a valid bus");
        let (from, span) = (f64::from(RIPPLE_FROM_DEAD_TIMES), f64::from(RIPPLE_FADE_DEAD_TIMES));
        // Spread = sqrt(3) |u| / Vdc for a vector at 30 deg off a phase axis (max - min
        // = sqrt(3) |u|), in dead times (Td/Ts = 0.02).
        for (dead_times, share) in [(from - 1.0, 0.0), (from + 0.5 * span, 0.5), (from + span + 1.0, 1.0)] {
            let mag = dead_times * 0.02 * vdc / 3f64.sqrt();
            let ang = core::f64::consts::FRAC_PI_6;
            let u_ab = AlphaBeta::new(mag * ang.cos(), mag * ang.sin());
            let (f, d) = (full.edge_ripple(u_ab, &bus), drive.edge_ripple(u_ab, &bus));
            for (f, d) in [(f.a, d.a), (f.b, d.b), (f.c, d.c)] {
                assert!((d - share * f).abs() < 1e-5 * f, "{dead_times}: {d} vs {share} x {f}");
            }
            assert!(f.a.max(f.b).max(f.c) > 0.0);
        }
    }
}
