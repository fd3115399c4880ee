//! Plant tests, each against an independent expectation (analytic phasor
//! solution, energy conservation, the classic dead-time estimate, the sensor
//! specification).

use super::*;
use dcfo::motor::MotorParams;

const TAU: f64 = 0.015;

/// Minimal complex arithmetic for phasors.
#[derive(Debug, Clone, Copy, PartialEq)]
struct C {
    re: f64,
    im: f64,
}

impl C {
    fn new(re: f64, im: f64) -> Self {
        C { re, im }
    }
    fn polar(r: f64, a: f64) -> Self {
        C::new(r * a.cos(), r * a.sin())
    }
    fn add(self, o: C) -> C {
        C::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: C) -> C {
        C::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: C) -> C {
        C::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn div(self, o: C) -> C {
        let n = o.re * o.re + o.im * o.im;
        C::new((self.re * o.re + self.im * o.im) / n, (self.im * o.re - self.re * o.im) / n)
    }
    fn scale(self, s: f64) -> C {
        C::new(self.re * s, self.im * s)
    }
    fn abs(self) -> f64 {
        self.re.hypot(self.im)
    }
    fn arg(self) -> f64 {
        self.im.atan2(self.re)
    }
}

fn wrap(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// Fourier coefficient of a real signal at angular frequency `w` (peak amplitude
/// phasor: `x = |X| cos(w t + arg X)`), over samples at times `t`.
fn dft_real(x: &[f64], t: &[f64], w: f64) -> C {
    let n = x.len() as f64;
    x.iter().zip(t).fold(C::new(0.0, 0.0), |acc, (&xi, &ti)| acc.add(C::polar(xi, -w * ti))).scale(2.0 / n)
}

/// Space-vector Fourier coefficient: `z = alpha + j beta`, component `Z e^{j w t}`.
fn dft_vector(a: &[f64], b: &[f64], t: &[f64], w: f64) -> C {
    let n = a.len() as f64;
    a.iter()
        .zip(b)
        .zip(t)
        .fold(C::new(0.0, 0.0), |acc, ((&ai, &bi), &ti)| acc.add(C::new(ai, bi).mul(C::polar(1.0, -w * ti))))
        .scale(1.0 / n)
}

fn paper() -> MotorParams {
    MotorParams::paper()
}

fn ideal() -> SimParams {
    SimParams::ideal_from_motor(&paper())
}

fn plant(p: &SimParams) -> Plant {
    match Plant::new(p) {
        Ok(p) => p,
        Err(e) => panic!("plant refused its parameters: {e}"),
    }
}

/// Runs `n` periods of a stationary-frame sinusoidal voltage command
/// `u = amp e^{j(w t + phi)}` (sampled at each period's midpoint, SVPWM on the
/// nominal bus), calling `record` before each step with the state at the valley
/// and after it with the state at the end of the period.
fn run_sine(
    pl: &mut Plant,
    n: usize,
    amp: f64,
    w: f64,
    phi: f64,
    mut record: impl FnMut(usize, &TrueState, &TrueState),
) {
    let ts = pl.pwm_period_s();
    let vdc = pl.params().inverter.dc_bus_v;
    for k in 0..n {
        let before = pl.state();
        let t_mid = before.t_s + 0.5 * ts;
        let u = C::polar(amp, w * t_mid + phi);
        pl.step(svpwm_duties(u.re, u.im, vdc), 0.0);
        let after = pl.state();
        record(k, &before, &after);
    }
}

#[test]
fn phasor_steady_state_surface_pm() {
    // Speed-clamped at 0.3 m/s (10 Hz), ideal inverter, 20 V at 100 deg ahead of
    // the PM flux. Expected: I = (U - j w psi_f) / (Rs + j w L) (space vectors).
    let p = ideal();
    let mut pl = plant(&p);
    let v = 0.3;
    let w = PI * v / TAU;
    let (amp, phi) = (20.0, 100f64.to_radians());
    if let Err(e) = pl.set_speed_clamp(Some(v)) {
        panic!("{e}");
    }
    let (settle, n) = (300, 1000); // 30 ms >> L/R = 1.7 ms; then one electrical period
    let (mut ia, mut ib, mut tt) = (vec![], vec![], vec![]);
    run_sine(&mut pl, settle + n, amp, w, phi, |k, s, _| {
        if k >= settle {
            ia.push(s.i_alpha_a);
            ib.push(s.i_beta_a);
            tt.push(s.t_s);
        }
    });
    let (rs, l, psi) = (p.plant.rs_ohm, p.plant.ld_h, p.plant.psi_f_wb);
    let expect = C::polar(amp, phi).sub(C::new(0.0, w * psi)).div(C::new(rs, w * l));
    let got = dft_vector(&ia, &ib, &tt, w);
    let neg = dft_vector(&ia, &ib, &tt, -w);
    let err = got.sub(expect).abs() / expect.abs();
    let dphi = wrap(got.arg() - expect.arg()).to_degrees();
    println!(
        "phasor: expected |I| {:.5} A at {:.3} deg, got {:.5} A at {:.3} deg; \
         vector error {:.4} % (phase {dphi:.4} deg), negative sequence {:.2e} A",
        expect.abs(),
        expect.arg().to_degrees(),
        got.abs(),
        got.arg().to_degrees(),
        100.0 * err,
        neg.abs()
    );
    // Tolerance 0.2 %: the valley sample differs from the period-mean current
    // only by second-order PWM-ripple terms, and the midpoint-held voltage loses
    // (w Ts)^2 / 24 = 2e-7 of its fundamental.
    assert!(err < 2e-3, "phasor error {:.4} %", 100.0 * err);
    assert!(neg.abs() < 1e-3 * expect.abs());
}

#[test]
fn phasor_steady_state_salient_dq() {
    // Ld != Lq: constant rotor-frame voltage through the PWM at 0.45 m/s; the
    // dq steady state solves [Rs, -w Lq; w Ld, Rs] i = [u_d; u_q - w psi_f].
    let mut p = ideal();
    p.plant.lq_h = 1.5 * p.plant.ld_h;
    p.plant.theta_offset_rad = 0.4;
    let mut pl = plant(&p);
    let v = 0.45;
    let w = PI * v / TAU;
    let (u_d, u_q) = (-6.0, 32.0);
    if let Err(e) = pl.set_speed_clamp(Some(v)).and_then(|_| pl.set_position(0.004)) {
        panic!("{e}");
    }
    let ts = pl.pwm_period_s();
    let vdc = p.inverter.dc_bus_v;
    let (settle, n) = (300, 1000);
    let (mut sd, mut sq) = (0.0, 0.0);
    for k in 0..settle + n {
        let s = pl.state();
        if k >= settle {
            sd += s.i_d_a;
            sq += s.i_q_a;
        }
        let th = s.theta_e_rad + w * 0.5 * ts;
        let u = C::new(u_d, u_q).mul(C::polar(1.0, th));
        pl.step(svpwm_duties(u.re, u.im, vdc), 0.0);
    }
    let (id, iq) = (sd / n as f64, sq / n as f64);
    let (rs, ld, lq, psi) = (p.plant.rs_ohm, p.plant.ld_h, p.plant.lq_h, p.plant.psi_f_wb);
    let b = u_q - w * psi;
    let det = rs * rs + w * w * ld * lq;
    let id_e = (rs * u_d + w * lq * b) / det;
    let iq_e = (rs * b - w * ld * u_d) / det;
    let err = (id - id_e).hypot(iq - iq_e) / id_e.hypot(iq_e);
    println!(
        "salient dq: expected ({id_e:.5}, {iq_e:.5}) A, got ({id:.5}, {iq:.5}) A, error {:.4} %",
        100.0 * err
    );
    assert!(err < 2e-3, "dq error {:.4} %", 100.0 * err);
}

/// Drives the q axis open loop from the true angle (as an encoder drive would)
/// with the segments `(u_q V, periods)`, returning how many periods ended stuck.
fn run_q_segments(pl: &mut Plant, segments: &[(f64, usize)], load_n: f64) -> usize {
    let ts = pl.pwm_period_s();
    let vdc = pl.params().inverter.dc_bus_v;
    let mut stuck = 0;
    for &(u_q, n) in segments {
        for _ in 0..n {
            let s = pl.state();
            let th = s.theta_e_rad + s.omega_e_rad_per_s * 0.5 * ts;
            let u = C::new(0.0, u_q).mul(C::polar(1.0, th));
            pl.step(svpwm_duties(u.re, u.im, vdc), load_n);
            if pl.state().stuck {
                stuck += 1;
            }
        }
    }
    stuck
}

#[test]
fn energy_balance_free_mechanics() {
    // Realistic plant, inverter (dead time, drops, bus ripple) and free mechanics
    // with friction, stiction, load and end-effect ripple: accelerate, reverse,
    // coast to a stop.
    let p = SimParams::from_motor(&paper());
    let mut pl = plant(&p);
    let e0 = pl.energy();
    let x0 = pl.state().x_m;
    let stuck = run_q_segments(&mut pl, &[(25.0, 500), (-25.0, 500), (0.0, 400)], 3.0);
    let e1 = pl.energy();
    let x1 = pl.state().x_m;

    let d_mag = e1.magnetic_j - e0.magnetic_j;
    let d_kin = e1.kinetic_j - e0.kinetic_j;
    let electrical = e1.motor_input_j - (e1.copper_j + d_mag + e1.thrust_work_j);
    let el_scale = e1.motor_input_j.abs() + e1.copper_j + e1.thrust_work_j.abs();
    let bus = e1.bus_j - (e1.motor_input_j + e1.device_j);
    let mech = e1.thrust_work_j - (d_kin + e1.friction_j + e1.load_j + e1.end_effect_j);
    let mech_scale = e1.friction_j + e1.load_j.abs() + e1.end_effect_j.abs() + e1.kinetic_j;
    let fem = p.plant.end_effect_ripple_n;
    let k = 2.0 * PI / TAU;
    let end_closed = fem / k * ((k * x1).sin() - (k * x0).sin());
    println!(
        "energy: bus {:.4} J = motor {:.4} J + devices {:.4} J (residual {:.2e} J); \
         motor = copper {:.4} + dmag {:.2e} + thrust {:.4} (residual {:.2e} J, rel {:.2e}); \
         thrust = dKE {:.2e} + friction {:.4} + load {:.4} + end {:.4} (residual {:.2e} J, rel {:.2e}); \
         end-effect closed form {:.6} vs {:.6}; stuck periods {stuck}",
        e1.bus_j,
        e1.motor_input_j,
        e1.device_j,
        bus,
        e1.copper_j,
        d_mag,
        e1.thrust_work_j,
        electrical,
        electrical / el_scale,
        d_kin,
        e1.friction_j,
        e1.load_j,
        e1.end_effect_j,
        mech,
        mech / mech_scale,
        end_closed,
        e1.end_effect_j
    );
    assert!(e1.device_j > 0.0 && e1.friction_j > 0.0 && e1.copper_j > 0.0);
    assert!(stuck > 0, "the coast-down should end held by static friction");
    // RK4 at <= 2 us on a ~1.7 ms electrical time constant: residuals of order
    // 1e-9 relative; 1e-6 leaves room without hiding a modelling error (a wrong
    // 1.5 factor or a sign error gives order-one residuals).
    // The whole chain at once: bus energy = copper + magnetic + kinetic +
    // friction + load + end-effect + device losses.
    let total =
        e1.bus_j - (e1.copper_j + d_mag + d_kin + e1.friction_j + e1.load_j + e1.end_effect_j + e1.device_j);
    println!("energy: total residual {total:.2e} J of {:.4} J", e1.bus_j);
    assert!(total.abs() < 1e-6 * (e1.bus_j.abs() + e1.copper_j + mech_scale));
    assert!(bus.abs() < 1e-9 * e1.bus_j.abs().max(1.0));
    assert!(electrical.abs() < 1e-6 * el_scale);
    assert!(mech.abs() < 1e-6 * mech_scale);
    assert!((end_closed - e1.end_effect_j).abs() < 1e-6 * fem * TAU);
}

/// Harmonics of the dead-time voltage error in a speed-clamped run at 0.3 m/s
/// with dead time `td_s`, no drops, and a sinusoidal command of `amp` volt at
/// 100 deg ahead of the PM flux.
struct DeadTimeHarmonics {
    /// `(4/pi) dV`, volt.
    h1: f64,
    /// Phase-a error harmonics 1, 3, 5, 7 (peak phasors), volt.
    e: [C; 4],
    /// Alpha-beta error components at +w, -5w, +7w, volt.
    v: [C; 3],
    /// Phase-a current fundamental, ampere.
    i1: C,
}

fn dead_time_harmonics(td_s: f64, amp: f64) -> DeadTimeHarmonics {
    let mut p = ideal();
    p.inverter.dead_time_s = td_s;
    let dv = p.inverter.dead_time_error_v();
    let mut pl = plant(&p);
    let v = 0.3;
    let w = PI * v / TAU;
    if let Err(e) = pl.set_speed_clamp(Some(v)) {
        panic!("{e}");
    }
    let (settle, n) = (300, 1000); // then exactly one electrical period
    let ts = pl.pwm_period_s();
    let (mut ea, mut eal, mut ebe, mut tm, mut ia, mut tv) = (vec![], vec![], vec![], vec![], vec![], vec![]);
    run_sine(&mut pl, settle + n, amp, w, 100f64.to_radians(), |k, s, a| {
        if k >= settle {
            let lp = &a.last_period;
            let cmd = lp.commanded_phase_v();
            let (ca, cb) = lp.commanded_alpha_beta_v();
            ea.push(lp.u_phase_avg_v[0] - cmd[0]);
            eal.push(lp.u_alpha_avg_v - ca);
            ebe.push(lp.u_beta_avg_v - cb);
            tm.push(s.t_s + 0.5 * ts);
            ia.push(s.i_abc_a[0]);
            tv.push(s.t_s);
        }
    });
    DeadTimeHarmonics {
        h1: 4.0 / PI * dv,
        e: [1.0, 3.0, 5.0, 7.0].map(|h| dft_real(&ea, &tm, h * w)),
        v: [1.0, -5.0, 7.0].map(|h| dft_vector(&eal, &ebe, &tm, h * w)),
        i1: dft_real(&ia, &tv, w),
    }
}

impl DeadTimeHarmonics {
    fn report(&self, label: &str) {
        let e1 = self.e[0].abs();
        let v1 = self.v[0].abs();
        println!(
            "dead time ({label}): (4/pi) dV {:.3} V; phase a: |E1| {e1:.3} V ({:+.2} %), |E3| {:.3} V, \
             5|E5|/|E1| {:.4}, 7|E7|/|E1| {:.4}; E1 vs -I1 {:.2} deg; alpha-beta: |E1| {v1:.3} V, \
             5|E-5|/|E1| {:.4}, 7|E7|/|E1| {:.4}; |I1| {:.3} A",
            self.h1,
            100.0 * (e1 / self.h1 - 1.0),
            self.e[1].abs(),
            5.0 * self.e[2].abs() / e1,
            7.0 * self.e[3].abs() / e1,
            self.phase_deg(),
            5.0 * self.v[1].abs() / v1,
            7.0 * self.v[2].abs() / v1,
            self.i1.abs()
        );
    }

    /// Angle of the error fundamental relative to the negative current fundamental, degree.
    fn phase_deg(&self) -> f64 {
        wrap(self.e[0].arg() - self.i1.arg() - PI).to_degrees()
    }
}

#[test]
fn dead_time_voltage_error_harmonics() {
    // The classic estimate: each leg's error is a square wave of height
    // dV = Td/Ts * Vdc against its current's sign; the star point removes only the
    // triplens, so the phase error has fundamental (4/pi) dV, 5th and 7th of 1/5
    // and 1/7 of it, no 3rd; the alpha-beta error vector has (4/pi) dV at +w,
    // 1/5 of it at -5w and 1/7 at +7w.
    // Its assumption, a current whose sign flips cleanly, holds when the voltage
    // driving the current (|U - E| = 19 V here) is large against dV: Td = 0.5 us
    // (dV = 1.56 V) and ~3.6 A. Tolerances: 2 % on the fundamental, 4 % on the
    // 5th/7th ratios (what remains of zero-current clamping and of the ~0.1 A
    // peak-to-peak PWM ripple near the zero crossings rounds the square wave).
    let r = dead_time_harmonics(0.5e-6, 30.0);
    r.report("Td 0.5 us, 30 V");
    let (e1, v1) = (r.e[0].abs(), r.v[0].abs());
    assert!((e1 / r.h1 - 1.0).abs() < 0.02);
    assert!((v1 / r.h1 - 1.0).abs() < 0.02);
    assert!(r.e[1].abs() < 0.01 * r.h1);
    assert!((5.0 * r.e[2].abs() / e1 - 1.0).abs() < 0.04);
    assert!((7.0 * r.e[3].abs() / e1 - 1.0).abs() < 0.04);
    assert!((5.0 * r.v[1].abs() / v1 - 1.0).abs() < 0.04);
    assert!((7.0 * r.v[2].abs() / v1 - 1.0).abs() < 0.04);
    // The late zero crossings of a clamped current delay the square wave by ~2 deg.
    assert!(r.phase_deg().abs() < 4.0, "error fundamental should oppose the current");
}

#[test]
fn dead_time_error_paper_defaults_light_current() {
    // Default 2 us dead time on the 311 V bus (dV = 6.2 V) with a 20 V command:
    // the error is as large as the net driving voltage, the current (~0.5 A) sits
    // at zero for ~10 % of each half period (zero-current clamping), and the
    // square-wave picture keeps only its fundamental (within 5 %); the 5th and
    // 7th fall well below 1/5 and 1/7. Printed for the drive simulation's authors.
    let r = dead_time_harmonics(2e-6, 20.0);
    r.report("Td 2 us, 20 V (paper defaults)");
    let e1 = r.e[0].abs();
    assert!((e1 / r.h1 - 1.0).abs() < 0.05);
    assert!(5.0 * r.e[2].abs() / e1 < 0.9 && 7.0 * r.e[3].abs() / e1 < 0.9);
}

#[test]
fn dead_time_error_with_constant_current_signs_is_exact() {
    // Standstill, no drops, DC currents (i_a > 0, i_b = i_c < 0) far from zero:
    // every leg loses or gains exactly Td * Vdc per period, so the phase-a error
    // is -dV (1 - (1 - 1 - 1) / 3) = -(4/3) dV.
    let mut p = ideal();
    p.inverter.dead_time_s = 2e-6;
    let dv = p.inverter.dead_time_error_v();
    let mut pl = plant(&p);
    if let Err(e) = pl.set_speed_clamp(Some(0.0)) {
        panic!("{e}");
    }
    let duties = svpwm_duties(20.0, 0.0, p.inverter.dc_bus_v);
    for _ in 0..100 {
        pl.step(duties, 0.0);
    }
    let s = pl.state();
    let got = s.last_period.u_phase_avg_v[0] - s.last_period.commanded_phase_v()[0];
    println!(
        "dead time, fixed signs: i_a {:.3} A, error {got:.6} V, expected {:.6} V",
        s.i_abc_a[0],
        -4.0 / 3.0 * dv
    );
    assert!(s.i_abc_a[0] > 1.0 && s.i_abc_a[1] < -0.5 && s.i_abc_a[2] < -0.5);
    assert!((got + 4.0 / 3.0 * dv).abs() < 1e-9 * dv);
}

#[test]
fn device_drop_error_matches_conduction_model() {
    // Standstill (speed clamped at 0), drops on, no dead time, a DC current
    // pattern held by a constant voltage: leg a carries i > 0, so its mean
    // voltage error is -(d (V_CE0 + r_CE i) + (1 - d)(V_F0 + r_F i)).
    let mut p = ideal();
    let inv = InverterParams::from_motor(&paper());
    p.inverter.igbt_threshold_v = inv.igbt_threshold_v;
    p.inverter.igbt_slope_ohm = inv.igbt_slope_ohm;
    p.inverter.diode_threshold_v = inv.diode_threshold_v;
    p.inverter.diode_slope_ohm = inv.diode_slope_ohm;
    let mut pl = plant(&p);
    if let Err(e) = pl.set_speed_clamp(Some(0.0)) {
        panic!("{e}");
    }
    let duties = svpwm_duties(12.0, 0.0, p.inverter.dc_bus_v);
    for _ in 0..200 {
        pl.step(duties, 0.0);
    }
    let before = pl.state();
    pl.step(duties, 0.0);
    let after = pl.state();
    let i = 0.5 * (before.i_abc_a[0] + after.i_abc_a[0]);
    let d = duties[0];
    let leg_err_a = -(d * (inv.igbt_threshold_v + inv.igbt_slope_ohm * i)
        + (1.0 - d) * (inv.diode_threshold_v + inv.diode_slope_ohm * i));
    // Legs b and c carry -i/2 each: into the leg, so IGBT when low, diode when high.
    let ib = 0.5 * i;
    let leg_err = |d: f64| {
        d * (inv.diode_threshold_v + inv.diode_slope_ohm * ib)
            + (1.0 - d) * (inv.igbt_threshold_v + inv.igbt_slope_ohm * ib)
    };
    let expect_a = leg_err_a - (leg_err_a + leg_err(duties[1]) + leg_err(duties[2])) / 3.0;
    let cmd = after.last_period.commanded_phase_v();
    let got_a = after.last_period.u_phase_avg_v[0] - cmd[0];
    println!("drops: i_a {i:.4} A, phase-a error expected {expect_a:.5} V, got {got_a:.5} V");
    assert!(i > 1.0);
    // 1 %: the slope terms use the period-mean current; PWM ripple is ~0.1 A.
    assert!((got_a - expect_a).abs() < 0.01 * expect_a.abs());
}

#[test]
fn ideal_inverter_average_is_command_and_timing() {
    // Ideal inverter, free mechanics: the period-average voltage equals the
    // commanded one, time advances by Ts per step, sampling is at the valley.
    let p = ideal();
    let mut pl = plant(&p);
    let mut t_prev = pl.time_s();
    for k in 0..50 {
        let a = 0.3 * k as f64;
        let d = [0.5 + 0.4 * a.sin(), 0.5 + 0.4 * a.cos(), 0.5 - 0.3 * a.sin()];
        pl.step(d, 0.0);
        let s = pl.state();
        let cmd = s.last_period.commanded_phase_v();
        for (got, want) in s.last_period.u_phase_avg_v.iter().zip(cmd) {
            assert!((got - want).abs() < 1e-9);
        }
        assert!((s.t_s - t_prev - 100e-6).abs() < 1e-15);
        t_prev = s.t_s;
        let r = pl.sample();
        assert_eq!(r.t_s, s.t_s);
    }
}

#[test]
fn ideal_sensors_read_the_true_state() {
    let mut p = SimParams::from_motor(&paper());
    p.sensors = SensorParams::ideal();
    let mut pl = plant(&p);
    run_q_segments(&mut pl, &[(30.0, 100)], 0.0);
    for _ in 0..20 {
        let s = pl.state();
        let r = pl.sample();
        for k in 0..3 {
            assert!((r.i_abc_a[k] - s.i_abc_a[k]).abs() < 1e-12);
        }
        assert!((r.i_alpha_a - s.i_alpha_a).abs() < 1e-12);
        assert!((r.i_beta_a - s.i_beta_a).abs() < 1e-12);
        assert_eq!(r.vdc_v, s.vdc_v);
        assert!(!r.current_saturated);
        pl.step([0.6, 0.4, 0.5], 0.0);
    }
}

/// A plant holding a DC current pattern at standstill, for sensor checks.
fn sensor_plant(sensors: SensorParams, seed: u64) -> Plant {
    let mut p = ideal();
    p.sensors = sensors;
    p.seed = seed;
    let mut pl = plant(&p);
    if let Err(e) = pl
        .set_speed_clamp(Some(0.0))
        .and_then(|_| pl.set_currents_dq(1.3, -0.7))
        .and_then(|_| pl.set_position(0.002))
    {
        panic!("{e}");
    }
    pl
}

#[test]
fn sensor_nonidealities_as_specified() {
    let real = SensorParams::from_motor(&paper());
    let base = SensorParams { current_sensing: CurrentSensing::ThreePhase, ..SensorParams::ideal() };
    // Offsets and gains, each phase its own.
    let mut pl = sensor_plant(
        SensorParams {
            current_offset_a: real.current_offset_a,
            current_gain_error: real.current_gain_error,
            bus_offset_v: real.bus_offset_v,
            bus_gain_error: real.bus_gain_error,
            ..base
        },
        1,
    );
    let s = pl.state();
    let r = pl.sample();
    for k in 0..3 {
        let e = (1.0 + real.current_gain_error[k]) * s.i_abc_a[k] + real.current_offset_a[k];
        assert!((r.i_abc_a[k] - e).abs() < 1e-12, "phase {k}");
    }
    let e = (1.0 + real.bus_gain_error) * s.vdc_v + real.bus_offset_v;
    assert!((r.vdc_v - e).abs() < 1e-9);

    // Two sensors: c is formed from a and b, so it carries both their errors.
    let mut pl = sensor_plant(
        SensorParams {
            current_sensing: CurrentSensing::TwoPhase,
            current_offset_a: real.current_offset_a,
            ..base
        },
        1,
    );
    let s = pl.state();
    let r = pl.sample();
    let oc = -(real.current_offset_a[0] + real.current_offset_a[1]);
    assert!((r.i_abc_a[2] - s.i_abc_a[2] - oc).abs() < 1e-12);
    assert!((r.i_alpha_a - s.i_alpha_a - real.current_offset_a[0]).abs() < 1e-12);

    // Quantisation: 12 bits over +-10 A and 0..500 V.
    let mut pl = sensor_plant(
        SensorParams {
            current_adc_bits: Some(12),
            current_full_scale_a: 10.0,
            bus_adc_bits: Some(12),
            bus_full_scale_v: 500.0,
            ..base
        },
        1,
    );
    let s = pl.state();
    let r = pl.sample();
    let lsb = 20.0 / 4096.0;
    for k in 0..3 {
        let codes = r.i_abc_a[k] / lsb;
        assert!((codes - codes.round()).abs() < 1e-9);
        assert!((r.i_abc_a[k] - s.i_abc_a[k]).abs() <= 0.5 * lsb + 1e-12);
    }
    let vlsb = 500.0 / 4096.0;
    assert!((r.vdc_v / vlsb - (r.vdc_v / vlsb).round()).abs() < 1e-9);
    assert!((r.vdc_v - s.vdc_v).abs() <= 0.5 * vlsb + 1e-9);
    assert!(!r.current_saturated);

    // Saturation at the ends of the range.
    if let Err(e) = pl.set_currents_dq(0.0, 15.0) {
        panic!("{e}");
    }
    let r = pl.sample();
    assert!(r.current_saturated);
    assert!(r.i_abc_a.iter().all(|i| i.abs() <= 10.0));

    // Noise: sample standard deviation of 4000 readings of a constant current.
    let mut pl = sensor_plant(SensorParams { current_noise_rms_a: 0.01, bus_noise_rms_v: 0.3, ..base }, 7);
    let s = pl.state();
    let n = 4000;
    let (mut m, mut q, mut mv, mut qv) = (0.0, 0.0, 0.0, 0.0);
    for _ in 0..n {
        let r = pl.sample();
        let e = r.i_abc_a[1] - s.i_abc_a[1];
        m += e;
        q += e * e;
        let ev = r.vdc_v - s.vdc_v;
        mv += ev;
        qv += ev * ev;
    }
    let (m, mv) = (m / n as f64, mv / n as f64);
    let sd = (q / n as f64 - m * m).sqrt();
    let sdv = (qv / n as f64 - mv * mv).sqrt();
    println!("noise: current sd {sd:.5} A (0.01), mean {m:.2e}; bus sd {sdv:.4} V (0.3)");
    // sd of a 4000-sample sd estimate is 1/sqrt(2n) = 1.1 %; 5 % is 4.5 sigma.
    assert!((sd / 0.01 - 1.0).abs() < 0.05);
    assert!((sdv / 0.3 - 1.0).abs() < 0.05);
    assert!(m.abs() < 5.0 * 0.01 / (n as f64).sqrt());
}

#[test]
fn default_parameters_for_the_paper_motor() {
    let p = SimParams::from_motor(&paper());
    assert!((p.inverter.dc_bus_v - 311.127).abs() < 1e-3);
    assert_eq!(p.sensors.current_full_scale_a, 10.0);
    assert_eq!(p.sensors.bus_full_scale_v, 500.0);
    assert!((rated_thrust_n(&paper()) - 149.3).abs() < 0.1);
    assert!((p.plant.coulomb_friction_n - 4.48).abs() < 0.01);
    assert!(p.validate().is_ok() && ideal().validate().is_ok());
    // Dead-time error vs back-EMF at 0.3 m/s, reported for the drive simulation.
    let dv = p.inverter.dead_time_error_v();
    let emf = PI * 0.3 / TAU * p.plant.psi_f_wb;
    println!("paper motor: dV {dv:.3} V, fundamental {:.3} V, back-EMF at 0.3 m/s {emf:.3} V", 4.0 / PI * dv);
}

#[test]
fn seeded_runs_repeat_and_seeds_differ() {
    let p = SimParams::from_motor(&paper());
    let read = |seed: u64| {
        let mut q = p;
        q.seed = seed;
        let mut pl = plant(&q);
        let mut out = vec![];
        for _ in 0..30 {
            pl.step([0.55, 0.5, 0.45], 0.0);
            let r = pl.sample();
            out.push((r.i_abc_a, r.vdc_v));
        }
        out
    };
    assert_eq!(read(5), read(5));
    assert_ne!(read(5), read(6));
}

#[test]
fn stiction_holds_then_releases() {
    // Ideal inverter, realistic friction and ripple; the mover sits where the
    // end-effect force is zero (x = tau / 4). Thrust 0.8 F_s: held; 1.5 F_s: moves.
    let mut p = ideal();
    p.plant = PlantParams::from_motor(&paper());
    let f_s = p.plant.static_friction_n;
    let k_f = 1.5 * PI / TAU * p.plant.psi_f_wb; // N per A of i_q
    let rs = p.plant.rs_ohm;
    let mut pl = plant(&p);
    if let Err(e) = pl.set_position(0.25 * TAU) {
        panic!("{e}");
    }
    let x0 = pl.state().x_m;
    run_q_segments(&mut pl, &[(rs * 0.8 * f_s / k_f, 200)], 0.0);
    let s = pl.state();
    assert!((s.thrust_n - 0.8 * f_s).abs() < 0.01 * f_s);
    assert!(s.stuck && s.v_m_per_s == 0.0 && s.x_m == x0);
    run_q_segments(&mut pl, &[(rs * 1.5 * f_s / k_f, 200)], 0.0);
    let s = pl.state();
    println!("stiction: released at 1.5 F_s, v {:.4} m/s", s.v_m_per_s);
    assert!(!s.stuck && s.v_m_per_s > 0.0 && s.x_m > x0);
}

#[test]
fn bad_parameters_and_inputs_are_refused_or_sanitised() {
    let mut p = ideal();
    p.inverter.dead_time_s = 60e-6;
    assert!(matches!(Plant::new(&p), Err(PlantError::InvalidParam { field: "dead_time_s", .. })));
    let mut p = ideal();
    p.plant.rs_ohm = f64::NAN;
    assert!(matches!(Plant::new(&p), Err(PlantError::InvalidParam { field: "rs_ohm", .. })));
    let mut p = ideal();
    p.sensors.current_adc_bits = Some(0);
    assert!(Plant::new(&p).is_err());
    let mut pl = plant(&ideal());
    assert!(pl.set_speed_clamp(Some(f64::INFINITY)).is_err());
    assert!(pl.set_currents_dq(f64::NAN, 0.0).is_err());
    pl.step([f64::NAN, 2.0, -1.0], f64::INFINITY);
    let s = pl.state();
    assert_eq!(s.last_period.duties, [0.5, 1.0, 0.0]);
    assert_eq!(s.last_period.load_force_n, 0.0);
    assert!(s.i_d_a.is_finite() && s.i_q_a.is_finite());
}

/// `motors/salient.toml` (Lq/Ld = 1.5), as the HFI tests use it: read from the file, so
/// the plant is tested on the motor the stroke and HFI drive tests run.
fn salient_motor() -> MotorParams {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../motors/salient.toml");
    crate::motor_file::load_motor(path).expect("motors/salient.toml").params
}

/// Square-wave injection `+-u_hf` along `theta - dth` (one PWM period each, from the
/// period's own duties, no computation delay) on top of a DC voltage `u_bias` along the
/// true d axis, the mover held at `theta` (rad). Returns the sign-weighted mean current
/// step per period in the injection frame, (d^, q^), over the last 400 of 1200 periods.
fn square_wave_response(p: &SimParams, theta: f64, dth: f64, u_hf: f64, u_bias: f64) -> (f64, f64) {
    let mut p = *p;
    p.plant.theta_offset_rad = theta;
    let mut pl = plant(&p);
    if let Err(e) = pl.set_speed_clamp(Some(0.0)) {
        panic!("{e}");
    }
    let vdc = p.inverter.dc_bus_v;
    let th = theta - dth;
    let (n, keep) = (1200, 400);
    let (mut sd, mut sq) = (0.0, 0.0);
    for k in 0..n {
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        let before = pl.state();
        let ua = u_bias * theta.cos() + sign * u_hf * th.cos();
        let ub = u_bias * theta.sin() + sign * u_hf * th.sin();
        pl.step(svpwm_duties(ua, ub, vdc), 0.0);
        let after = pl.state();
        if k >= n - keep {
            let (da, db) = (after.i_alpha_a - before.i_alpha_a, after.i_beta_a - before.i_beta_a);
            sd += sign * (da * th.cos() + db * th.sin());
            sq += sign * (db * th.cos() - da * th.sin());
        }
    }
    (sd / keep as f64, sq / keep as f64)
}

/// The analytic response of the module docs of `dcfo::algorithms::hfi`: per true axis the periodic
/// steady state of a square wave through R-L, `2 (U_x / R) tanh(R T / 2 L_x)` (`U T / L`
/// to second order), rotated into the injection frame.
fn square_wave_expected(rs: f64, ld: f64, lq: f64, ts: f64, dth: f64, u_hf: f64) -> (f64, f64) {
    let step = |u: f64, l: f64| 2.0 * u / rs * (rs * ts / (2.0 * l)).tanh();
    let di_d = step(u_hf * dth.cos(), ld);
    let di_q = step(-u_hf * dth.sin(), lq);
    (di_d * dth.cos() - di_q * dth.sin(), di_d * dth.sin() + di_q * dth.cos())
}

#[test]
fn hf_square_wave_response_matches_the_analysis() {
    // Salient motor, ideal inverter: the HFI's demodulated d^ and q^ responses at known
    // angle errors equal U T (S + D cos 2 dth) and U T D sin 2 dth (with R: tanh), to
    // 0.3 % of U T S (the PWM's pulse shape within a period enters at second order).
    let m = salient_motor();
    let p = SimParams::ideal_from_motor(&m);
    let ts = p.inverter.pwm_period_s;
    let u_hf = 38.18; // V; the response is linear in it (dcfo::algorithms::hfi injects 63.6 V here)
    let (rs, ld, lq) = (p.plant.rs_ohm, p.plant.ld_h, p.plant.lq_h);
    let scale = u_hf * ts * 0.5 * (1.0 / ld + 1.0 / lq);
    for dth_deg in [0.0f64, 15.0, 45.0, -30.0, 80.0] {
        let dth = dth_deg.to_radians();
        let (d, q) = square_wave_response(&p, 0.9, dth, u_hf, 0.0);
        let (de, qe) = square_wave_expected(rs, ld, lq, ts, dth, u_hf);
        println!("dth {dth_deg:5.1}: d^ {d:.5} (analysis {de:.5}) A, q^ {q:.5} ({qe:.5}) A");
        assert!((d - de).abs() < 3e-3 * scale, "{dth_deg}: d^ {d} vs {de}");
        assert!((q - qe).abs() < 3e-3 * scale, "{dth_deg}: q^ {q} vs {qe}");
    }
}

#[test]
fn hf_square_wave_response_through_dead_time() {
    // The realistic inverter (2 us dead time, device drops). With a DC current whose
    // phase currents all keep their sign through the HF swing (mover aligned with phase
    // a, 2 A on d: phases at 2, -1, -1 A against a swing of +-0.35 A), the dead time's
    // error is the same in both half periods and the response is the analytic one (the
    // devices' slope adds 0.12 ohm to R: second order). With no DC current every phase
    // crosses zero with the HF, and the dead time takes up to (4/3) V_dt of the
    // injected vector (V_dt = V_bus t_dead / T = 5.7 V of 38 V here): the response
    // shrinks, by at most that fraction.
    let m = salient_motor();
    let mut p = SimParams::from_motor(&m);
    p.plant = PlantParams::ideal_from_motor(&m);
    p.inverter.bus_ripple_v = 0.0;
    p.sensors = SensorParams::ideal();
    let ts = p.inverter.pwm_period_s;
    let u_hf = 38.18;
    let (rs, ld, lq) = (p.plant.rs_ohm, p.plant.ld_h, p.plant.lq_h);
    let scale = u_hf * ts * 0.5 * (1.0 / ld + 1.0 / lq);
    let v_dt = p.inverter.dead_time_error_v();
    for dth_deg in [0.0f64, 20.0, -35.0] {
        let dth = dth_deg.to_radians();
        // Bias voltage for about 2 A: R I + the dead time's and the devices' drop.
        let (d, q) = square_wave_response(&p, 0.0, dth, u_hf, 2.0 * rs + 4.0 / 3.0 * v_dt + 2.0);
        let (de, qe) = square_wave_expected(rs, ld, lq, ts, dth, u_hf);
        println!("biased, dth {dth_deg:5.1}: d^ {d:.5} (analysis {de:.5}) A, q^ {q:.5} ({qe:.5}) A");
        assert!((d - de).abs() < 3e-3 * scale, "{dth_deg}: d^ {d} vs {de}");
        assert!((q - qe).abs() < 3e-3 * scale, "{dth_deg}: q^ {q} vs {qe}");
        let (d0, q0) = square_wave_response(&p, 0.0, dth, u_hf, 0.0);
        let loss = 1.0 - d0 / de;
        println!(
            "no DC,  dth {dth_deg:5.1}: d^ {d0:.5} A ({:.1} % below the analysis; bound {:.1} %), q^ {q0:.5} A",
            100.0 * loss,
            100.0 * 4.0 / 3.0 * v_dt / u_hf
        );
        assert!(loss > 0.0 && loss < 4.0 / 3.0 * v_dt / u_hf, "{dth_deg}: {loss}");
    }
}

#[test]
fn d_saturation_is_off_by_default_and_shapes_the_flux_as_documented() {
    let m = salient_motor();
    let mut p = SimParams::ideal_from_motor(&m);
    assert_eq!(p.plant.ld_saturation_per_a, 0.0);
    let i_pk = 3.0 * 2f64.sqrt();
    let c = PlantParams::d_saturation_for(0.1, i_pk);
    assert!((c - 0.02389).abs() < 1e-4, "{c}");
    p.plant.ld_saturation_per_a = c;
    let model = Model::new(&p.plant, &p.inverter);
    // Incremental inductance 10 % low at +I_pk, 10 % high at -I_pk; the flux is its
    // integral (central difference).
    assert!((model.ld_incremental(i_pk) / m.ld_h as f64 - 0.9).abs() < 1e-9);
    assert!((model.ld_incremental(-i_pk) / m.ld_h as f64 - 1.1).abs() < 1e-9);
    for i in [-8.0, -1.0, 0.0, 0.5, 3.0, 40.0] {
        let h = 1e-5;
        let slope = (model.flux_d(i + h) - model.flux_d(i - h)) / (2.0 * h);
        assert!((slope - model.ld_incremental(i)).abs() < 1e-9, "{i}: {slope}");
    }
    assert_eq!(model.flux_d(0.0), p.plant.psi_f_wb);
    // A d voltage pulse of flux L_d I_pk from rest: the current peaks higher along the
    // magnet than against it, as the flux curve says (resistance aside).
    let peak = |sign: f64| {
        let mut pl = plant(&p);
        if let Err(e) = pl.set_speed_clamp(Some(0.0)) {
            panic!("{e}");
        }
        let u = 50.0 * sign;
        let n = (m.ld_h as f64 * i_pk / (50.0 * 100e-6)).round() as usize;
        for _ in 0..n {
            pl.step(svpwm_duties(u, 0.0, p.inverter.dc_bus_v), 0.0);
        }
        pl.state().i_d_a.abs()
    };
    let (plus, minus) = (peak(1.0), peak(-1.0));
    println!("d pulse peaks: +{plus:.4} A, -{minus:.4} A");
    assert!(plus > 1.05 * minus, "{plus} {minus}");
}
