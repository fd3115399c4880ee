//! Frequency responses of the flux observers, as in the paper's Fig. 8: the transfer
//! from back-EMF `e` (V) to flux estimate `psi_hat` (Wb), so magnitudes are in Wb/V
//! (= s) and a perfect integrator is `1/s`.
//!
//! - DCFO (docs/method.md §3): `psi_hat = H(s) x` with `x = e/s` the open-loop flux, so
//!   `psi_hat / e = H(s)/s = 2 zeta w Ls s / (Ls s^3 + (2 zeta w Ls - h) s^2 + w^2 Ls s - h w^2)`
//!   with the notch at `w` and `h = h_per_ls_omega * Ls * w` (ohm). At `s = j w` this is
//!   exactly `1/(j w)`: the integrator's gain and phase (-90 deg) at the fundamental.
//! - CFO (LPF): `1/(s + wc)`.
//! - Pure integrator: `1/s`.
//!
//! [`measure_response`] drives the library's discrete observers (`f64`, SI) with a
//! sinusoidal back-EMF and measures gain and phase by complex demodulation, so the
//! figure shows the implementation sitting on the analysis.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use dcfo::algorithms::observer::{
    Dcfo, DcfoConfig, FluxObserver, LpfObserver, ObserverInput, ObserverKind, ObserverMotor, PureIntegrator,
};
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::estimator::EstimatorConfig;
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;

use super::{Figure, Panel, PlotError, Series, write_figure};

/// A number with up to 3 decimals, trailing zeros removed (`10`, `2.5`, `0.707`).
fn short(x: f64) -> String {
    let s = format!("{x:.3}");
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s }
}

/// A complex number `re + j im`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct C {
    re: f64,
    im: f64,
}

impl C {
    fn new(re: f64, im: f64) -> C {
        C { re, im }
    }
    fn add(self, o: C) -> C {
        C::new(self.re + o.re, self.im + o.im)
    }
    fn mul(self, o: C) -> C {
        C::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn div(self, o: C) -> C {
        let d = o.re * o.re + o.im * o.im;
        C::new((self.re * o.re + self.im * o.im) / d, (self.im * o.re - self.re * o.im) / d)
    }
    fn scale(self, k: f64) -> C {
        C::new(self.re * k, self.im * k)
    }
    /// `c[0] + c[1] s + c[2] s^2 + ...` at `s`.
    fn poly(coeffs: &[f64], s: C) -> C {
        coeffs.iter().rev().fold(C::new(0.0, 0.0), |acc, &c| acc.mul(s).add(C::new(c, 0.0)))
    }
}

/// A back-EMF-to-flux filter (the continuous-time model of an observer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FluxFilter {
    /// The DCFO: `H(s)/s` with the notch held at `omega0_rad_s`.
    Dcfo {
        /// Notch (fundamental) frequency, rad/s (> 0).
        omega0_rad_s: f64,
        /// Notch damping (dimensionless, > 0).
        zeta: f64,
        /// Disturbance feedback gain h, ohm (< 0).
        h_ohm: f64,
        /// Inductance Ls, H (> 0).
        ls_h: f64,
    },
    /// The CFO's low-pass filter `1/(s + wc)`.
    Lpf {
        /// Cut-off `wc`, rad/s (> 0).
        cutoff_rad_s: f64,
    },
    /// The pure integrator `1/s`.
    Integrator,
}

impl FluxFilter {
    /// The DCFO with the library's default tuning ([`DcfoConfig::default`]) on the
    /// paper motor (Ls = 8.5 mH), notch at `omega0_rad_s`.
    pub fn dcfo_default(omega0_rad_s: f64) -> FluxFilter {
        let cfg = DcfoConfig::default();
        let ls_h = f64::from(MotorParams::paper().lq_h);
        FluxFilter::Dcfo {
            omega0_rad_s,
            zeta: f64::from(cfg.zeta),
            h_ohm: f64::from(cfg.h_per_ls_omega) * ls_h * omega0_rad_s,
            ls_h,
        }
    }

    /// The CFO with the library's default cut-off
    /// ([`EstimatorConfig::for_motor`]: 2 pi * 2.5 Hz).
    pub fn cfo_default() -> FluxFilter {
        let cfg = EstimatorConfig::for_motor(&MotorParams::paper(), ObserverKind::Cfo);
        FluxFilter::Lpf { cutoff_rad_s: f64::from(cfg.cfo_cutoff_rad_s) }
    }

    /// `psi_hat / e` at angular frequency `omega_rad_s` (rad/s) as `(re, im)`, Wb/V.
    pub fn response(&self, omega_rad_s: f64) -> (f64, f64) {
        let s = C::new(0.0, omega_rad_s);
        let g = match *self {
            FluxFilter::Dcfo { omega0_rad_s: w, zeta, h_ohm: h, ls_h: ls } => {
                let num = C::poly(&[0.0, 2.0 * zeta * w * ls], s);
                let den = C::poly(&[-h * w * w, w * w * ls, 2.0 * zeta * w * ls - h, ls], s);
                num.div(den)
            }
            FluxFilter::Lpf { cutoff_rad_s } => C::new(1.0, 0.0).div(s.add(C::new(cutoff_rad_s, 0.0))),
            FluxFilter::Integrator => C::new(1.0, 0.0).div(s),
        };
        (g.re, g.im)
    }
}

/// A frequency response sampled at frequencies `freq_hz` (Hz): magnitude in dB re
/// 1 Wb/V and phase in degrees, in (-180, 180] (no unwrapping is needed: the DCFO's
/// phase runs from +90 to -180 deg, approaching -180 from above, the LPF's from 0 to
/// -90 deg).
#[derive(Clone, Debug, PartialEq)]
pub struct Bode {
    /// Frequencies, Hz.
    pub freq_hz: Vec<f64>,
    /// Magnitude `20 log10 |psi_hat / e|`, dB re 1 Wb/V.
    pub mag_db: Vec<f64>,
    /// Phase of `psi_hat / e`, degrees.
    pub phase_deg: Vec<f64>,
}

/// The analytic frequency response of `filter` at `freq_hz` (Hz).
pub fn bode(filter: &FluxFilter, freq_hz: &[f64]) -> Bode {
    let mut mag_db = Vec::with_capacity(freq_hz.len());
    let mut phase_deg = Vec::with_capacity(freq_hz.len());
    for &f in freq_hz {
        let (re, im) = filter.response(2.0 * PI * f);
        mag_db.push(20.0 * re.hypot(im).log10());
        phase_deg.push(im.atan2(re).to_degrees());
    }
    Bode { freq_hz: freq_hz.to_vec(), mag_db, phase_deg }
}

/// `per_decade` logarithmically spaced frequencies from `lo_hz` to `hi_hz` (Hz), both
/// included.
pub fn log_frequencies(lo_hz: f64, hi_hz: f64, per_decade: usize) -> Vec<f64> {
    let decades = (hi_hz / lo_hz).log10();
    let n = ((decades * per_decade as f64).ceil() as usize).max(1);
    (0..=n).map(|k| lo_hz * 10f64.powf(decades * k as f64 / n as f64)).collect()
}

/// Measures the library's discrete observer that `filter` models, at `f_hz` (Hz),
/// sample period `dt_s` (s): returns `psi_hat / e` as `(re, im)`, Wb/V.
///
/// The observer (`f64`, SI, zero current so `e = u`) is driven with the rotating
/// back-EMF `e = A exp(j w t)` (alpha = real part, beta = imaginary part), each period's
/// held voltage being that period's exact mean, so the integral of the held voltage is
/// the integral of `e`. After a settling time (2 s: over 40 time constants of the
/// slowest pole of the default DCFO at 10 Hz and of the CFO) the estimate is
/// demodulated, `mean(psi_c(t_k) exp(-j w t_k)) / A`, over whole periods (at least
/// 1 s). For [`FluxFilter::Dcfo`] the notch is held at its `omega0_rad_s`.
pub fn measure_response(filter: &FluxFilter, f_hz: f64, dt_s: f64) -> Result<(f64, f64), PlotError> {
    let refuse = |reason: String| PlotError::Measure { reason };
    if !(f_hz > 0.0 && dt_s > 0.0 && f_hz * dt_s < 0.25) {
        return Err(refuse(format!("frequency {f_hz} Hz with period {dt_s} s: need 0 < f < 1/(4 dt)")));
    }
    let base = Base::SI;
    let motor = MotorParams::paper();
    let (mut observer, omega_e): (Box<dyn FluxObserver<f64>>, f64) = match *filter {
        FluxFilter::Dcfo { omega0_rad_s, zeta, h_ohm, ls_h } => {
            let m = ObserverMotor { rs: 0.0, ls: ls_h, saliency: 0.0 };
            let cfg = DcfoConfig {
                zeta: zeta as f32,
                h_per_ls_omega: (h_ohm / (ls_h * omega0_rad_s)) as f32,
                ..DcfoConfig::default()
            };
            let o = Dcfo::<f64>::new(m, &cfg, &base).map_err(|e| refuse(format!("DCFO: {e:?}")))?;
            (Box::new(o), omega0_rad_s)
        }
        FluxFilter::Lpf { cutoff_rad_s } => {
            let m = ObserverMotor::new(&motor, &base);
            let o = LpfObserver::<f64>::new(m, cutoff_rad_s).map_err(|e| refuse(format!("LPF: {e:?}")))?;
            (Box::new(o), 0.0)
        }
        FluxFilter::Integrator => {
            (Box::new(PureIntegrator::<f64>::new(ObserverMotor::new(&motor, &base))), 0.0)
        }
    };
    let w = 2.0 * PI * f_hz;
    let settle = (2.0 / dt_s).round() as usize;
    let period_samples = 1.0 / (f_hz * dt_s);
    let periods = (1.0 / (period_samples * dt_s)).ceil().max(2.0);
    let measure = (periods * period_samples).round() as usize;
    let mut acc = C::new(0.0, 0.0);
    let phasor = |t: f64| C::new((w * t).cos(), (w * t).sin());
    for n in 1..=settle + measure {
        let (t0, t1) = ((n - 1) as f64 * dt_s, n as f64 * dt_s);
        // Mean of exp(j w t) over [t0, t1]: (exp(j w t1) - exp(j w t0)) / (j w dt).
        let diff = phasor(t1).add(phasor(t0).scale(-1.0));
        let u = diff.div(C::new(0.0, w * dt_s));
        let input = ObserverInput {
            u_ab: AlphaBeta::new(u.re, u.im),
            i_ab: AlphaBeta::new(0.0, 0.0),
            omega_e,
            dt: dt_s,
        };
        let psi = observer.update(&input).map_err(|e| refuse(format!("{f_hz} Hz: observer fault {e:?}")))?;
        if n > settle {
            let conj = C::new((w * t1).cos(), -(w * t1).sin());
            acc = acc.add(C::new(psi.psi_ab.alpha, psi.psi_ab.beta).mul(conj));
        }
    }
    let g = acc.scale(1.0 / measure as f64);
    Ok((g.re, g.im))
}

/// What [`bode_figure`] draws.
#[derive(Clone, Debug, PartialEq)]
pub struct BodeSetup {
    /// The DCFO model (its notch frequency is marked on the figure).
    pub dcfo: FluxFilter,
    /// The CFO's low-pass filter.
    pub cfo: FluxFilter,
    /// Frequency range of the curves, Hz `(low, high)`.
    pub range_hz: (f64, f64),
    /// Frequencies (Hz) at which the discrete observers are measured.
    pub measure_hz: Vec<f64>,
    /// Sample period of the discrete observers, s.
    pub dt_s: f64,
}

impl BodeSetup {
    /// The paper's setting: DCFO with the default tuning and the notch at 10 Hz
    /// (0.3 m/s on the paper motor), CFO cut-off 2.5 Hz, 0.1 Hz to 1 kHz, observers
    /// measured at 10 kHz from 0.5 Hz to 500 Hz.
    pub fn paper() -> BodeSetup {
        BodeSetup {
            dcfo: FluxFilter::dcfo_default(2.0 * PI * 10.0),
            cfo: FluxFilter::cfo_default(),
            range_hz: (0.1, 1000.0),
            measure_hz: vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0],
            dt_s: 1e-4,
        }
    }
}

/// A measured point of a discrete observer next to its model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasuredPoint {
    /// Frequency, Hz.
    pub f_hz: f64,
    /// Measured magnitude, dB re 1 Wb/V.
    pub mag_db: f64,
    /// Measured phase, degrees (within 180 degrees of the model's).
    pub phase_deg: f64,
    /// `|measured - model| / |model|` (dimensionless).
    pub rel_error: f64,
}

/// Measures the observer that `filter` models at each of `freq_hz` (Hz), sample period
/// `dt_s` (s); see [`measure_response`].
pub fn measured_points(
    filter: &FluxFilter,
    freq_hz: &[f64],
    dt_s: f64,
) -> Result<Vec<MeasuredPoint>, PlotError> {
    freq_hz
        .iter()
        .map(|&f| {
            let (re, im) = measure_response(filter, f, dt_s)?;
            let model = filter.response(2.0 * PI * f);
            let model_phase = model.1.atan2(model.0).to_degrees();
            let mut phase = im.atan2(re).to_degrees();
            phase -= 360.0 * ((phase - model_phase) / 360.0).round();
            let rel_error = (re - model.0).hypot(im - model.1) / model.0.hypot(model.1);
            Ok(MeasuredPoint { f_hz: f, mag_db: 20.0 * re.hypot(im).log10(), phase_deg: phase, rel_error })
        })
        .collect()
}

/// What [`bode_figure`] wrote and measured.
#[derive(Clone, Debug, PartialEq)]
pub struct BodeFigure {
    /// The files written: PNG, then SVG.
    pub files: [PathBuf; 2],
    /// The discrete DCFO's measured points.
    pub dcfo: Vec<MeasuredPoint>,
    /// The discrete CFO's measured points.
    pub cfo: Vec<MeasuredPoint>,
}

/// Draws the Bode plot of `setup` (magnitude in dB re 1 Wb/V and phase in degrees of
/// back-EMF to flux, against frequency in Hz on a log axis) to `STEM.png` and
/// `STEM.svg`: the DCFO's `H(s)/s`, the CFO's `1/(s + wc)` and the pure integrator
/// `1/s`, with the measured points of the discrete DCFO and CFO.
pub fn bode_figure(stem: &Path, setup: &BodeSetup) -> Result<BodeFigure, PlotError> {
    let freqs = log_frequencies(setup.range_hz.0, setup.range_hz.1, 80);
    let (dcfo_label, f0_hz) = match setup.dcfo {
        FluxFilter::Dcfo { omega0_rad_s, zeta, h_ohm, ls_h } => (
            format!(
                "DCFO H(s)/s: notch {} Hz, ζ = {}, h = {}·Ls·ω",
                short(omega0_rad_s / (2.0 * PI)),
                short(zeta),
                short(h_ohm / (ls_h * omega0_rad_s))
            ),
            Some(omega0_rad_s / (2.0 * PI)),
        ),
        other => (format!("{other:?}"), None),
    };
    let cfo_label = match setup.cfo {
        FluxFilter::Lpf { cutoff_rad_s } => {
            format!("CFO 1/(s + ωc): fc = {} Hz", short(cutoff_rad_s / (2.0 * PI)))
        }
        other => format!("{other:?}"),
    };
    let curves = [
        (dcfo_label, bode(&setup.dcfo, &freqs)),
        (cfo_label, bode(&setup.cfo, &freqs)),
        ("pure integrator 1/s".to_string(), bode(&FluxFilter::Integrator, &freqs)),
    ];
    let measured_dcfo = measured_points(&setup.dcfo, &setup.measure_hz, setup.dt_s)?;
    let measured_cfo = measured_points(&setup.cfo, &setup.measure_hz, setup.dt_s)?;

    let colors = [super::PALETTE[3], super::PALETTE[0], super::PALETTE[7]];
    let mut mag = Vec::new();
    let mut phase = Vec::new();
    for ((name, b), color) in curves.iter().zip(colors) {
        let pts = |y: &[f64]| b.freq_hz.iter().copied().zip(y.iter().copied()).collect::<Vec<_>>();
        mag.push(Series::line(name.as_str(), pts(&b.mag_db)).with_color(color));
        phase.push(Series::line("", pts(&b.phase_deg)).with_color(color));
    }
    let fs_khz = 1e-3 / setup.dt_s;
    for (name, points, color) in [
        (format!("DCFO, library observer at {fs_khz} kHz (measured)"), &measured_dcfo, colors[0]),
        (format!("CFO, library observer at {fs_khz} kHz (measured)"), &measured_cfo, colors[1]),
    ] {
        mag.push(
            Series::markers(name, points.iter().map(|p| (p.f_hz, p.mag_db)).collect()).with_color(color),
        );
        phase.push(
            Series::markers("", points.iter().map(|p| (p.f_hz, p.phase_deg)).collect()).with_color(color),
        );
    }
    let lo_db = curves.iter().flat_map(|c| &c.1.mag_db).fold(f64::INFINITY, |a, &b| a.min(b));
    let hi_db = curves.iter().flat_map(|c| &c.1.mag_db).fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    let (lo_db, hi_db) = ((lo_db / 10.0).floor() * 10.0, (hi_db / 10.0).ceil() * 10.0);
    if let Some(f0) = f0_hz {
        let name = format!("fundamental (notch) {} Hz", short(f0));
        mag.push(Series::dashed(name, vec![(f0, lo_db), (f0, hi_db)]).with_color((90, 90, 90)));
        phase.push(Series::dashed("", vec![(f0, -180.0), (f0, 90.0)]).with_color((90, 90, 90)));
    }
    let figure = Figure {
        title: "Back-EMF e to flux estimate ψ: DCFO, CFO (LPF) and pure integrator".into(),
        x_label: "frequency (Hz)".into(),
        x_log: true,
        x_range: Some(setup.range_hz),
        panels: vec![
            Panel::new("magnitude (dB re 1 Wb/V)", mag).with_y_range(lo_db, hi_db),
            Panel::new("phase (deg)", phase).with_y_range(-190.0, 100.0),
        ],
        size: Some((1200, 900)),
    };
    let files = write_figure(&figure, stem)?;
    Ok(BodeFigure { files, dcfo: measured_dcfo, cfo: measured_cfo })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn dcfo_is_an_exact_integrator_at_the_fundamental() {
        for f0 in [2.0, 10.0, 15.0, 50.0] {
            let w0 = 2.0 * PI * f0;
            let dcfo = FluxFilter::dcfo_default(w0);
            let (re, im) = dcfo.response(w0);
            // psi/e = 1/(j w0) = -j/w0: gain 1/w0 (0 dB relative), phase -90 deg.
            assert!(close(re * w0, 0.0, 1e-12) && close(im * w0, -1.0, 1e-12), "{f0}: {re} {im}");
            let b = bode(&dcfo, &[f0]);
            assert!(close(b.mag_db[0], -20.0 * w0.log10(), 1e-9));
            assert!(close(b.phase_deg[0], -90.0, 1e-9));
        }
    }

    #[test]
    fn dcfo_rejects_dc_and_rolls_off_faster_than_the_integrator() {
        let w0 = 2.0 * PI * 10.0;
        let dcfo = FluxFilter::dcfo_default(w0);
        let b = bode(&dcfo, &[1e-3, 1e-2, 1e3, 1e4]);
        // A zero at the origin: +20 dB/decade and +90 deg at low frequency (H(0) = 0).
        assert!(close(b.mag_db[1] - b.mag_db[0], 20.0, 0.01), "{:?}", b.mag_db);
        assert!(close(b.phase_deg[0], 90.0, 0.05), "{:?}", b.phase_deg);
        // Two more poles than zeros: -40 dB/decade and towards -180 deg at high frequency.
        assert!(close(b.mag_db[3] - b.mag_db[2], -40.0, 0.05), "{:?}", b.mag_db);
        assert!(b.phase_deg[3] < -179.0 && b.phase_deg[3] > -180.0, "{:?}", b.phase_deg);
        // The phase is continuous along a dense sweep: no wrap at +-180 deg.
        let sweep = bode(&dcfo, &log_frequencies(0.01, 1e4, 50));
        assert!(sweep.phase_deg.windows(2).all(|w| (w[1] - w[0]).abs() < 20.0));
    }

    #[test]
    fn lpf_and_integrator_known_values() {
        let wc = 2.0 * PI * 2.5;
        let lpf = FluxFilter::cfo_default();
        assert_eq!(lpf, FluxFilter::Lpf { cutoff_rad_s: f64::from((2.0 * std::f32::consts::PI) * 2.5) });
        let b = bode(&lpf, &[2.5, 10.0]);
        // At the cut-off: 1/(wc sqrt 2), -45 deg.
        assert!(close(b.mag_db[0], -20.0 * (wc * 2f64.sqrt()).log10(), 1e-5));
        assert!(close(b.phase_deg[0], -45.0, 1e-4));
        // At 10 Hz: phase -90 + atan(wc/w) = -75.96 deg, i.e. it leads the integrator by
        // 14.04 deg (the CFO's angle error of the paper's Fig. 17).
        assert!(close(b.phase_deg[1], -90.0 + (2.5f64 / 10.0).atan().to_degrees(), 1e-4));
        let w = 2.0 * PI * 10.0;
        assert!(close(b.mag_db[1], -20.0 * (w * w + wc * wc).sqrt().log10(), 1e-5));
        let i = bode(&FluxFilter::Integrator, &[1.0, 10.0]);
        assert!(close(i.mag_db[0] - i.mag_db[1], 20.0, 1e-12));
        assert!(i.phase_deg.iter().all(|&p| close(p, -90.0, 1e-12)));
    }

    #[test]
    fn the_discrete_observers_sit_on_the_analytic_curves() {
        let setup = BodeSetup::paper();
        for filter in [setup.dcfo, setup.cfo] {
            let pts = measured_points(&filter, &setup.measure_hz, setup.dt_s).unwrap();
            let worst = pts.iter().map(|p| p.rel_error).fold(0.0, f64::max);
            eprintln!("{filter:?}: worst relative error {worst:.2e} over {:?} Hz", setup.measure_hz);
            assert!(worst < 0.02, "{filter:?}: worst relative error {worst}: {pts:?}");
        }
        // At the fundamental the discrete DCFO is an exact integrator (pre-warped SOGI).
        let w0 = 2.0 * PI * 10.0;
        let (re, im) = measure_response(&setup.dcfo, 10.0, setup.dt_s).unwrap();
        assert!(close(re * w0, 0.0, 1e-9) && close(im * w0, -1.0, 1e-9), "{re} {im}");
    }

    #[test]
    fn bode_figure_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let keep = std::env::var_os("DCFO_KEEP_PLOTS").map(PathBuf::from);
        let out = keep.as_deref().unwrap_or(dir.path());
        let setup = BodeSetup::paper();
        let fig = bode_figure(&out.join("bode"), &setup).unwrap();
        assert_eq!((fig.dcfo.len(), fig.cfo.len()), (10, 10));
        let [png, svg] = fig.files;
        assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
        let svg = std::fs::read_to_string(&svg).unwrap();
        assert!(svg.contains("frequency (Hz)") && svg.contains("pure integrator"));
    }
}
