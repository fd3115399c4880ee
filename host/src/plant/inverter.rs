//! Two-level inverter: centre-aligned PWM timing with dead time, and the leg
//! voltage of each conduction state including device drops.

/// Conduction state of one leg over a sub-interval of the PWM period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LegMode {
    /// Upper switch gated on (the upper IGBT or, for negative current, the upper diode conducts).
    Upper,
    /// Lower switch gated on.
    Lower,
    /// Both switches off (dead time): a free-wheeling diode chosen by the current sign conducts.
    Dead,
}

/// The gate command of one leg as carried from one period to the next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LegCommand {
    /// `true` while the upper switch is commanded on.
    pub high: bool,
    /// Time of the last command change, second, relative to the start of the
    /// period about to be built (so zero or negative; `-inf` = long ago).
    pub since_s: f64,
}

impl LegCommand {
    /// Lower switch commanded on since long ago (the state at power-up).
    pub(crate) const IDLE: LegCommand = LegCommand { high: false, since_s: f64::NEG_INFINITY };
}

/// Most switching-relevant instants one period can hold: per leg, one carried
/// turn-on plus up to three command changes, each with its delayed turn-on,
/// plus the period's two ends.
const MAX_BREAKPOINTS: usize = 3 * 7 + 2;

/// The switching pattern of one PWM period, built from the duties.
#[derive(Debug, Clone)]
pub(crate) struct PeriodSchedule {
    prev: [LegCommand; 3],
    /// Command changes inside the period per leg: (time s, new level), in time order.
    changes: [[(f64, bool); 3]; 3],
    n_changes: [usize; 3],
    dead_time_s: f64,
    period_s: f64,
    breakpoints: [f64; MAX_BREAKPOINTS],
    n_breakpoints: usize,
}

impl PeriodSchedule {
    /// Builds the period `[0, period_s)` for duties already clamped to `[0, 1]`.
    /// The upper switch of leg k is commanded on over
    /// `[(1 - d) Ts / 2, (1 + d) Ts / 2)`; each turn-on happens `dead_time_s`
    /// after its command (and not at all if the command is withdrawn first).
    pub(crate) fn new(prev: [LegCommand; 3], duties: [f64; 3], period_s: f64, dead_time_s: f64) -> Self {
        let mut changes = [[(0.0, false); 3]; 3];
        let mut n_changes = [0usize; 3];
        let mut bps = [0.0; MAX_BREAKPOINTS];
        let mut n = 0usize;
        let mut push = |t: f64, bps: &mut [f64; MAX_BREAKPOINTS]| {
            if t > 0.0 && t < period_s && n < MAX_BREAKPOINTS - 2 {
                bps[n] = t;
                n += 1;
            }
        };
        for k in 0..3 {
            let d = duties[k];
            let start_high = d >= 1.0;
            let mut list: [(f64, bool); 3] = [(0.0, false); 3];
            let mut m = 0usize;
            if start_high != prev[k].high {
                list[m] = (0.0, start_high);
                m += 1;
            }
            if d > 0.0 && d < 1.0 {
                list[m] = (0.5 * (1.0 - d) * period_s, true);
                m += 1;
                list[m] = (0.5 * (1.0 + d) * period_s, false);
                m += 1;
            }
            push(prev[k].since_s + dead_time_s, &mut bps);
            for &(t, _) in &list[..m] {
                push(t, &mut bps);
                push(t + dead_time_s, &mut bps);
            }
            changes[k] = list;
            n_changes[k] = m;
        }
        bps[n] = 0.0;
        n += 1;
        bps[n] = period_s;
        n += 1;
        let slice = &mut bps[..n];
        slice.sort_unstable_by(f64::total_cmp);
        // Drop instants closer together than a femtosecond-scale fraction of the period.
        let tol = 1e-12 * period_s;
        let mut m = 1usize;
        for i in 1..n {
            if slice[i] - slice[m - 1] > tol {
                slice[m] = slice[i];
                m += 1;
            }
        }
        // Make sure the last breakpoint is exactly the period end.
        slice[m - 1] = period_s;
        PeriodSchedule { prev, changes, n_changes, dead_time_s, period_s, breakpoints: bps, n_breakpoints: m }
    }

    /// Sorted instants `0 = t_0 < t_1 < ... = Ts`, second, between which every
    /// leg's conduction mode is constant.
    pub(crate) fn breakpoints(&self) -> &[f64] {
        &self.breakpoints[..self.n_breakpoints]
    }

    /// The command of leg `k` in force at time `t` (s, within the period) and
    /// the time it has been in force, second.
    fn command_at(&self, k: usize, t: f64) -> (bool, f64) {
        let mut level = self.prev[k].high;
        let mut since = self.prev[k].since_s;
        for &(tc, l) in &self.changes[k][..self.n_changes[k]] {
            if tc <= t {
                level = l;
                since = tc;
            }
        }
        (level, t - since)
    }

    /// Conduction mode of leg `k` at time `t` (s, within the period). Evaluate
    /// it strictly inside a breakpoint interval.
    pub(crate) fn mode_at(&self, k: usize, t: f64) -> LegMode {
        let (high, age) = self.command_at(k, t);
        if age < self.dead_time_s {
            LegMode::Dead
        } else if high {
            LegMode::Upper
        } else {
            LegMode::Lower
        }
    }

    /// The gate commands to carry into the next period.
    pub(crate) fn carry(&self) -> [LegCommand; 3] {
        let mut out = [LegCommand::IDLE; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let (high, age) = self.command_at(k, self.period_s);
            *o = LegCommand { high, since_s: -age };
        }
        out
    }
}

/// On-state models of the switching devices, `drop = threshold + slope * |i|`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Devices {
    pub igbt_v0: f64,
    pub igbt_r: f64,
    pub diode_v0: f64,
    pub diode_r: f64,
}

/// Leg output of one conduction state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LegOutput {
    /// Leg voltage to the negative DC rail, volt.
    pub v: f64,
    /// Current drawn from the positive rail by this leg, ampere.
    pub i_plus: f64,
    /// Conduction loss in the leg's devices, watt.
    pub loss_w: f64,
}

/// Leg voltage for conduction `mode`, with the current direction `sign`
/// (`+1`: current out of the leg into the motor, `-1`: into the leg, `0`: none)
/// frozen over the integration step, and phase current `i` (A) of the RK4 stage.
/// `upper_last` is the side that conducted last (used only for `Dead` at zero
/// current, where the floating leg keeps its last voltage).
///
/// By construction `vdc * i_plus - v * i = loss_w` exactly.
pub(crate) fn leg_output(
    mode: LegMode,
    sign: i8,
    upper_last: bool,
    i: f64,
    vdc: f64,
    dev: &Devices,
) -> LegOutput {
    // Which rail the leg is tied to and through which device.
    enum Path {
        UpperIgbt,
        UpperDiode,
        LowerIgbt,
        LowerDiode,
        UpperIdeal,
        LowerIdeal,
    }
    let path = match (mode, sign) {
        (LegMode::Upper, s) if s > 0 => Path::UpperIgbt,
        (LegMode::Upper, s) if s < 0 => Path::UpperDiode,
        (LegMode::Upper, _) => Path::UpperIdeal,
        (LegMode::Lower, s) if s < 0 => Path::LowerIgbt,
        (LegMode::Lower, s) if s > 0 => Path::LowerDiode,
        (LegMode::Lower, _) => Path::LowerIdeal,
        (LegMode::Dead, s) if s > 0 => Path::LowerDiode,
        (LegMode::Dead, s) if s < 0 => Path::UpperDiode,
        (LegMode::Dead, _) => {
            if upper_last {
                Path::UpperIdeal
            } else {
                Path::LowerIdeal
            }
        }
    };
    match path {
        // Current out of the leg through the upper IGBT: v = Vdc - drop.
        Path::UpperIgbt => {
            let drop = dev.igbt_v0 + dev.igbt_r * i;
            LegOutput { v: vdc - drop, i_plus: i, loss_w: drop * i }
        }
        // Current into the leg, back to the + rail through the upper diode: v = Vdc + drop.
        Path::UpperDiode => {
            let drop = dev.diode_v0 - dev.diode_r * i;
            LegOutput { v: vdc + drop, i_plus: i, loss_w: -drop * i }
        }
        // Current into the leg, down through the lower IGBT: v = +drop.
        Path::LowerIgbt => {
            let drop = dev.igbt_v0 - dev.igbt_r * i;
            LegOutput { v: drop, i_plus: 0.0, loss_w: -drop * i }
        }
        // Current out of the leg, up from the - rail through the lower diode: v = -drop.
        Path::LowerDiode => {
            let drop = dev.diode_v0 + dev.diode_r * i;
            LegOutput { v: -drop, i_plus: 0.0, loss_w: drop * i }
        }
        Path::UpperIdeal => LegOutput { v: vdc, i_plus: i, loss_w: 0.0 },
        Path::LowerIdeal => LegOutput { v: 0.0, i_plus: 0.0, loss_w: 0.0 },
    }
}

/// Duty cycles (each in `[0, 1]`) that make an ideal inverter on a `vdc_v` bus
/// apply the stationary-frame voltage `(u_alpha_v, u_beta_v)` (volt,
/// amplitude-invariant) on average over a period: sinusoidal references plus the
/// min-max zero-sequence offset (equivalent to symmetric SVPWM), linear up to
/// `|u| = vdc_v / sqrt(3)`; beyond that each duty is clamped to `[0, 1]`.
/// A non-finite input or a non-positive bus gives `[0.5; 3]` (zero voltage).
pub fn svpwm_duties(u_alpha_v: f64, u_beta_v: f64, vdc_v: f64) -> [f64; 3] {
    if !(u_alpha_v.is_finite() && u_beta_v.is_finite() && vdc_v.is_finite() && vdc_v > 0.0) {
        return [0.5; 3];
    }
    let h = 0.5 * 3f64.sqrt();
    let ua = u_alpha_v;
    let ub = -0.5 * u_alpha_v + h * u_beta_v;
    let uc = -0.5 * u_alpha_v - h * u_beta_v;
    let offset = -0.5 * (ua.max(ub).max(uc) + ua.min(ub).min(uc));
    [ua, ub, uc].map(|u| (0.5 + (u + offset) / vdc_v).clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    const TS: f64 = 100e-6;

    fn high_time(s: &PeriodSchedule, k: usize) -> (f64, f64) {
        let bp = s.breakpoints();
        let (mut up, mut dead) = (0.0, 0.0);
        for w in bp.windows(2) {
            match s.mode_at(k, 0.5 * (w[0] + w[1])) {
                LegMode::Upper => up += w[1] - w[0],
                LegMode::Dead => dead += w[1] - w[0],
                LegMode::Lower => {}
            }
        }
        (up, dead)
    }

    #[test]
    fn schedule_mid_duty_has_two_dead_intervals() {
        let s = PeriodSchedule::new([LegCommand::IDLE; 3], [0.3, 0.5, 0.9], TS, 2e-6);
        for (k, d) in [0.3, 0.5, 0.9].into_iter().enumerate() {
            let (up, dead) = high_time(&s, k);
            assert!((up - (d * TS - 2e-6)).abs() < 1e-15, "leg {k}: up {up}");
            assert!((dead - 4e-6).abs() < 1e-15, "leg {k}: dead {dead}");
        }
        let c = s.carry();
        assert!(c.iter().all(|c| !c.high && c.since_s < -2e-6));
    }

    #[test]
    fn schedule_swallowed_pulse_and_carry_over() {
        // d = 0.01: 1 us command pulse, shorter than the dead time: the upper switch
        // never turns on and the leg is dead for 1 us + 2 us.
        let s = PeriodSchedule::new([LegCommand::IDLE; 3], [0.01, 0.0, 1.0], TS, 2e-6);
        let (up, dead) = high_time(&s, 0);
        assert_eq!(up, 0.0);
        assert!((dead - 3e-6).abs() < 1e-15);
        // d = 1 after an idle lower command: dead for 2 us from the valley, then upper.
        let (up, dead) = high_time(&s, 2);
        assert!((up - (TS - 2e-6)).abs() < 1e-15 && (dead - 2e-6).abs() < 1e-15);
        // Next period d = 0.5 on leg c: the command drops at the valley, lower on after 2 us.
        let s2 = PeriodSchedule::new(s.carry(), [0.0, 0.0, 0.5], TS, 2e-6);
        let (up, dead) = high_time(&s2, 2);
        assert!((up - (0.5 * TS - 2e-6)).abs() < 1e-15);
        assert!((dead - 6e-6).abs() < 1e-15, "dead {dead}");
    }

    #[test]
    fn schedule_turn_on_delay_crosses_the_valley() {
        // d = 0.99: the upper command ends 0.5 us before the period end; the
        // lower turn-on falls 1.5 us into the next period.
        let s = PeriodSchedule::new([LegCommand::IDLE; 3], [0.99, 0.5, 0.5], TS, 2e-6);
        let s2 = PeriodSchedule::new(s.carry(), [0.5, 0.5, 0.5], TS, 2e-6);
        let bp = s2.breakpoints();
        assert!(bp.iter().any(|&t| (t - 1.5e-6).abs() < 1e-15));
        assert_eq!(s2.mode_at(0, 0.7e-6), LegMode::Dead);
        assert_eq!(s2.mode_at(0, 1.6e-6), LegMode::Lower);
    }

    #[test]
    fn leg_output_power_identity() {
        let dev = Devices { igbt_v0: 1.0, igbt_r: 0.12, diode_v0: 0.9, diode_r: 0.12 };
        for mode in [LegMode::Upper, LegMode::Lower, LegMode::Dead] {
            for (sign, i) in [(1i8, 2.0), (-1, -1.5), (0, 0.0), (1, -0.01)] {
                let o = leg_output(mode, sign, true, i, 311.0, &dev);
                let residual = 311.0 * o.i_plus - o.v * i - o.loss_w;
                assert!(residual.abs() < 1e-12, "{mode:?} {sign} {i}");
                if sign != 0 && sign as f64 * i > 0.0 {
                    assert!(o.loss_w > 0.0);
                }
            }
        }
    }

    #[test]
    fn svpwm_average_voltage_is_the_reference() {
        let vdc = 311.0;
        for k in 0..12 {
            let a = k as f64 * 0.5;
            let (ua, ub) = (150.0 * a.cos(), 150.0 * a.sin());
            let d = svpwm_duties(ua, ub, vdc);
            let m = (d[0] + d[1] + d[2]) / 3.0;
            let v = d.map(|x| (x - m) * vdc);
            let alpha = (2.0 * v[0] - v[1] - v[2]) / 3.0;
            let beta = (v[1] - v[2]) / 3f64.sqrt();
            assert!((alpha - ua).abs() < 1e-9 && (beta - ub).abs() < 1e-9);
        }
        assert_eq!(svpwm_duties(f64::NAN, 0.0, 311.0), [0.5; 3]);
    }
}
