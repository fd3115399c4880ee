//! Figures: stacked panels of named series sharing one x axis, written as both PNG and
//! SVG with plotters.
//!
//! A [`Figure`] has a title, an x axis (label with unit, linear or logarithmic) and one
//! or more [`Panel`]s stacked vertically; each panel has a y label (with unit), a legend
//! and any number of [`Series`] (lines or markers). [`write_figure`] renders it to
//! `STEM.png` and `STEM.svg`. [`time_series_figure`] is the usual case (x = time in s);
//! [`bode::bode_figure`] draws the observers' frequency responses.
//!
//! Text is drawn with DejaVu Sans, embedded in the binary (crate `dejavu`) and rendered
//! with ab_glyph (see `text.rs`), so no system font library (fontconfig, freetype) is
//! needed. In the SVG the text stays text (`font-family="sans-serif"`), drawn by the
//! viewer.
//!
//! Long series are thinned for drawing: above [`MAX_LINE_POINTS`] points a line keeps
//! the minimum and maximum of each bucket of consecutive points, so the envelope (peaks,
//! spikes) is drawn exactly while files stay small. Non-finite points are left out.

pub mod bode;
mod text;

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ab_glyph::FontRef;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;

use text::GlyphText;

/// A colour, `(red, green, blue)`.
pub type Rgb = (u8, u8, u8);

/// Colours given to series without their own, in order (matplotlib's "tab10").
pub const PALETTE: [Rgb; 8] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
];

/// Lines with more points than this are thinned to min/max per bucket for drawing.
pub const MAX_LINE_POINTS: usize = 4000;

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeriesStyle {
    /// A solid line through the points.
    Line,
    /// A dashed line through the points (references, limits).
    Dashed,
    /// A filled circle at each point (measurements).
    Markers,
}

/// One named series of `(x, y)` points, in the units of its figure's x axis and its
/// panel's y axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// The points, in x order for lines.
    pub points: Vec<(f64, f64)>,
    /// How it is drawn.
    pub style: SeriesStyle,
    /// Its colour; `None`: the next [`PALETTE`] colour by position in the panel.
    pub color: Option<Rgb>,
}

impl Series {
    /// A solid line.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { name: name.into(), points, style: SeriesStyle::Line, color: None }
    }

    /// A dashed line.
    pub fn dashed(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { style: SeriesStyle::Dashed, ..Series::line(name, points) }
    }

    /// Markers at the points.
    pub fn markers(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { style: SeriesStyle::Markers, ..Series::line(name, points) }
    }

    /// A line from separate x and y samples (pairs up to the shorter of the two).
    pub fn from_xy(name: impl Into<String>, x: &[f64], y: &[f64]) -> Self {
        Series::line(name, x.iter().copied().zip(y.iter().copied()).collect())
    }

    /// The same series in colour `rgb`.
    pub fn with_color(self, rgb: Rgb) -> Self {
        Series { color: Some(rgb), ..self }
    }
}

/// One panel: a y axis and its series.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// y-axis label, with its unit, e.g. `"angle error (deg, electrical)"`.
    pub y_label: String,
    /// The series, drawn in order (later ones on top).
    pub series: Vec<Series>,
    /// Fixed y range (in y units); `None`: fitted to the data with a 5 % margin.
    pub y_range: Option<(f64, f64)>,
}

impl Panel {
    /// A panel with an automatic y range.
    pub fn new(y_label: impl Into<String>, series: Vec<Series>) -> Self {
        Panel { y_label: y_label.into(), series, y_range: None }
    }

    /// The same panel with a fixed y range.
    pub fn with_y_range(self, lo: f64, hi: f64) -> Self {
        Panel { y_range: Some((lo, hi)), ..self }
    }
}

/// A figure: stacked panels sharing one x axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    /// Title, drawn above the panels.
    pub title: String,
    /// x-axis label, with its unit, e.g. `"time (s)"`.
    pub x_label: String,
    /// Logarithmic x axis (all x must then be > 0).
    pub x_log: bool,
    /// Fixed x range (in x units); `None`: the data's extent.
    pub x_range: Option<(f64, f64)>,
    /// The panels, top to bottom.
    pub panels: Vec<Panel>,
    /// Image size in pixels `(width, height)`; `None`: 1200 wide, 320 per panel.
    pub size: Option<(u32, u32)>,
}

/// A figure whose x axis is time in seconds (`"time (s)"`, linear).
pub fn time_series_figure(title: impl Into<String>, panels: Vec<Panel>) -> Figure {
    Figure {
        title: title.into(),
        x_label: "time (s)".into(),
        x_log: false,
        x_range: None,
        panels,
        size: None,
    }
}

/// Why a figure could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The figure has no panel, or an axis has no finite data to scale to.
    #[error("figure `{title}`: {reason}")]
    Empty {
        /// The figure's title.
        title: String,
        /// What is missing.
        reason: String,
    },
    /// The embedded font could not be registered with plotters.
    #[error("cannot register the embedded DejaVu Sans font with plotters")]
    Font,
    /// The output directory could not be created.
    #[error("{dir}: {source}")]
    Io {
        /// The directory.
        dir: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A discrete observer could not be measured (see [`bode::measure_response`]).
    #[error("measuring an observer's frequency response: {reason}")]
    Measure {
        /// What went wrong.
        reason: String,
    },
    /// Drawing or writing an image failed.
    #[error("{file}: {message}")]
    Draw {
        /// The image file.
        file: String,
        /// plotters' message.
        message: String,
    },
}

/// DejaVu Sans, parsed once; also registered as plotters' `sans-serif`, which plotters
/// uses to size the legend box.
fn font() -> Result<FontRef<'static>, PlotError> {
    static FONT: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FONT.get_or_init(|| {
        let bytes = dejavu::sans::regular();
        let registered = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok();
        FontRef::try_from_slice(bytes).ok().filter(|_| registered)
    })
    .clone()
    .ok_or(PlotError::Font)
}

/// Renders `figure` to `STEM.png` and `STEM.svg` (`stem` without extension; its
/// directory is created if needed) and returns the two paths, PNG first.
pub fn write_figure(figure: &Figure, stem: &Path) -> Result<[PathBuf; 2], PlotError> {
    let font = font()?;
    let layout = Layout::of(figure)?;
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|source| PlotError::Io { dir: dir.display().to_string(), source })?;
    }
    let png = with_extension(stem, "png");
    let svg = with_extension(stem, "svg");
    let size = figure.size.unwrap_or((1200, 70 + 320 * figure.panels.len() as u32));
    let draw_err = |file: &Path| {
        let file = file.display().to_string();
        move |message: String| PlotError::Draw { file: file.clone(), message }
    };
    let bitmap = GlyphText { inner: BitMapBackend::new(&png, size), font: font.clone(), render_text: true };
    draw_figure(bitmap.into_drawing_area(), figure, &layout).map_err(draw_err(&png))?;
    let vector = GlyphText { inner: SVGBackend::new(&svg, size), font, render_text: false };
    draw_figure(vector.into_drawing_area(), figure, &layout).map_err(draw_err(&svg))?;
    Ok([png, svg])
}

fn with_extension(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

/// Axis ranges, fixed before drawing.
struct Layout {
    x: Range<f64>,
    y: Vec<Range<f64>>,
}

impl Layout {
    fn of(figure: &Figure) -> Result<Layout, PlotError> {
        let empty =
            |reason: &str| PlotError::Empty { title: figure.title.clone(), reason: reason.to_string() };
        if figure.panels.is_empty() {
            return Err(empty("no panels"));
        }
        let usable_x = |x: f64| x.is_finite() && (!figure.x_log || x > 0.0);
        let x = match figure.x_range {
            Some((lo, hi)) if usable_x(lo) && usable_x(hi) && lo < hi => lo..hi,
            Some(_) => return Err(empty("x range is empty, not finite, or not positive on a log axis")),
            None => {
                let xs = figure.panels.iter().flat_map(|p| &p.series).flat_map(|s| &s.points).map(|p| p.0);
                let (lo, hi) =
                    extent(xs.filter(|&x| usable_x(x))).ok_or_else(|| empty("no finite x data"))?;
                if lo < hi {
                    lo..hi
                } else if figure.x_log {
                    lo / 2.0..hi * 2.0
                } else {
                    lo - 0.5..hi + 0.5
                }
            }
        };
        let y = figure
            .panels
            .iter()
            .map(|p| match p.y_range {
                Some((lo, hi)) if lo.is_finite() && hi.is_finite() && lo < hi => Ok(lo..hi),
                Some(_) => Err(empty(&format!("panel `{}`: y range is empty or not finite", p.y_label))),
                None => {
                    let ys = p
                        .series
                        .iter()
                        .flat_map(|s| &s.points)
                        .filter(|q| x.contains(&q.0) || q.0 == x.end)
                        .map(|q| q.1);
                    Ok(match extent(ys.filter(|y| y.is_finite())) {
                        Some((lo, hi)) if lo < hi => {
                            let m = 0.05 * (hi - lo);
                            lo - m..hi + m
                        }
                        Some((v, _)) => v - 0.5f64.max(v.abs() * 0.1)..v + 0.5f64.max(v.abs() * 0.1),
                        None => -1.0..1.0,
                    })
                }
            })
            .collect::<Result<_, _>>()?;
        Ok(Layout { x, y })
    }
}

fn extent(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

fn draw_figure<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    figure: &Figure,
    layout: &Layout,
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let body = root.titled(&figure.title, ("sans-serif", 24)).map_err(e)?;
    let areas = body.split_evenly((figure.panels.len(), 1));
    let last = figure.panels.len() - 1;
    for (k, ((area, panel), y)) in areas.iter().zip(&figure.panels).zip(&layout.y).enumerate() {
        let x_label = (k == last).then_some(figure.x_label.as_str());
        let x = layout.x.clone();
        if figure.x_log {
            let x_min = f64::MIN_POSITIVE;
            draw_panel(area, x.log_scale(), x_min, y.clone(), panel, x_label, &format_log_tick).map_err(e)?;
        } else {
            let tiny = 1e-9 * (x.end - x.start);
            let x_format = move |v: &f64| format_tick(if v.abs() < tiny { &0.0 } else { v });
            draw_panel(area, x, f64::NEG_INFINITY, y.clone(), panel, x_label, &x_format).map_err(e)?;
        }
    }
    root.present().map_err(e)
}

/// Draws one panel; points with `x < x_min` are left out.
fn draw_panel<DB, X>(
    area: &DrawingArea<DB, Shift>,
    x: X,
    x_min: f64,
    y: Range<f64>,
    panel: &Panel,
    x_label: Option<&str>,
    x_format: &dyn Fn(&f64) -> String,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    // Ticks computed as multiples of a step can miss zero by rounding (-2.8e-17).
    let tiny = 1e-9 * (y.end - y.start).abs();
    let y_format = move |v: &f64| format_tick(if v.abs() < tiny { &0.0 } else { v });
    let mut chart = ChartBuilder::on(area)
        .margin_top(8)
        .margin_right(20)
        .margin_left(8)
        .margin_bottom(if x_label.is_some() { 8 } else { 0 })
        .x_label_area_size(if x_label.is_some() { 56 } else { 30 })
        .y_label_area_size(78)
        .build_cartesian_2d(x, y)?;
    let mut mesh = chart.configure_mesh();
    mesh.x_label_formatter(x_format)
        .y_label_formatter(&y_format)
        .y_desc(panel.y_label.as_str())
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .light_line_style(RGBColor(0, 0, 0).mix(0.06));
    if let Some(label) = x_label {
        mesh.x_desc(label);
    }
    mesh.draw()?;

    let mut named = 0;
    for (k, s) in panel.series.iter().enumerate() {
        let (r, g, b) = s.color.unwrap_or(PALETTE[k % PALETTE.len()]);
        let color = RGBColor(r, g, b);
        // Leaves out non-finite points, and x <= 0 on a log axis (`x_min > 0` there).
        let finite: Vec<(f64, f64)> =
            s.points.iter().copied().filter(|p| p.0.is_finite() && p.1.is_finite() && p.0 >= x_min).collect();
        let legend_color = color;
        let annotated = match s.style {
            SeriesStyle::Line => {
                chart.draw_series(LineSeries::new(thin(&finite, MAX_LINE_POINTS), color.stroke_width(2)))?
            }
            SeriesStyle::Dashed => chart.draw_series(DashedLineSeries::new(
                thin(&finite, MAX_LINE_POINTS),
                8,
                5,
                color.stroke_width(2),
            ))?,
            SeriesStyle::Markers => chart
                .draw_series(finite.iter().map(|&p| Circle::new(p, 4, ShapeStyle::from(&color).filled())))?,
        };
        if s.name.is_empty() {
            continue;
        }
        named += 1;
        annotated.label(s.name.as_str()).legend(move |(x, y)| -> DynElement<'static, DB, (i32, i32)> {
            match s.style {
                SeriesStyle::Markers => {
                    Circle::new((x + 10, y), 4, ShapeStyle::from(&legend_color).filled()).into_dyn()
                }
                _ => PathElement::new(vec![(x, y), (x + 20, y)], legend_color.stroke_width(2)).into_dyn(),
            }
        });
    }
    if named > 0 {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(0, 0, 0).mix(0.4))
            .label_font(("sans-serif", 15))
            .draw()?;
    }
    Ok(())
}

/// Tick label: up to 4 significant digits, no trailing zeros.
fn format_tick(v: &f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.1e}");
    }
    let decimals = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s }
}

/// Log-axis tick label: `0.1`, `1`, `10`, `100`, `1k`, `10k`.
fn format_log_tick(v: &f64) -> String {
    if *v >= 1000.0 { format!("{}k", format_tick(&(v / 1000.0))) } else { format_tick(v) }
}

/// At most about `max` points: per bucket of consecutive points, the lowest and the
/// highest (in their order), plus the last point, so peaks survive.
fn thin(points: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max {
        return points.to_vec();
    }
    let buckets = (max / 2).max(1);
    let size = points.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(2 * buckets + 1);
    for chunk in points.chunks(size) {
        let (mut lo, mut hi) = (0, 0);
        for (k, p) in chunk.iter().enumerate() {
            if p.1 < chunk[lo].1 {
                lo = k;
            }
            if p.1 > chunk[hi].1 {
                hi = k;
            }
        }
        let (a, b) = if lo <= hi { (lo, hi) } else { (hi, lo) };
        out.push(chunk[a]);
        if b != a {
            out.push(chunk[b]);
        }
    }
    if let Some(&last) = points.last()
        && out.last() != Some(&last)
    {
        out.push(last);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(n: usize, f_hz: f64, amp: f64) -> Vec<(f64, f64)> {
        (0..n)
            .map(|k| (k as f64 * 1e-4, amp * (2.0 * std::f64::consts::PI * f_hz * k as f64 * 1e-4).sin()))
            .collect()
    }

    #[test]
    fn a_time_series_figure_is_written_as_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let fig = time_series_figure(
            "Replay at 0.3 m/s: estimated angle and flux",
            vec![
                Panel::new(
                    "flux (Wb)",
                    vec![
                        Series::line("psi_alpha", sine(20_000, 10.0, 0.16)),
                        Series::dashed("psi_f", vec![(0.0, 0.16), (2.0, 0.16)]),
                    ],
                ),
                Panel::new(
                    "angle error (deg, electrical)",
                    vec![Series::line("DCFO", sine(20_000, 3.0, 2.0))],
                )
                .with_y_range(-5.0, 5.0),
            ],
        );
        let keep = std::env::var_os("DCFO_KEEP_PLOTS").map(PathBuf::from);
        let out = keep.as_deref().unwrap_or(dir.path());
        let [png, svg] = write_figure(&fig, &out.join("sub/replay")).unwrap();
        assert_eq!(png, out.join("sub/replay.png"));
        let png_bytes = std::fs::read(&png).unwrap();
        assert!(png_bytes.len() > 10_000 && png_bytes.starts_with(b"\x89PNG"), "{}", png_bytes.len());
        let svg_text = std::fs::read_to_string(&svg).unwrap();
        assert!(svg_text.contains("<svg") && svg_text.contains("psi_alpha"), "{}", &svg_text[..200]);
        assert!(svg_text.contains("angle error (deg, electrical)"));
        // 20 000 points are thinned: the SVG stays small.
        assert!(svg_text.len() < 600_000, "{}", svg_text.len());
    }

    #[test]
    fn empty_figures_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let fig = time_series_figure("nothing", vec![]);
        assert!(write_figure(&fig, &dir.path().join("a")).unwrap_err().to_string().contains("no panels"));
        let fig =
            time_series_figure("nan", vec![Panel::new("y", vec![Series::line("s", vec![(f64::NAN, 1.0)])])]);
        assert!(write_figure(&fig, &dir.path().join("b")).unwrap_err().to_string().contains("no finite x"));
        assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
    }

    #[test]
    fn thinning_keeps_the_envelope() {
        let mut pts = sine(100_000, 10.0, 1.0);
        pts[54_321].1 = 7.0; // a spike
        let t = thin(&pts, 4000);
        assert!(t.len() <= 4001, "{}", t.len());
        assert!(t.iter().any(|p| p.1 == 7.0));
        assert_eq!(t.first(), pts.first());
        assert_eq!(t.last(), pts.last());
        assert!(t.windows(2).all(|w| w[0].0 < w[1].0));
        assert_eq!(thin(&pts[..10], 4000).len(), 10);
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(format_tick(&0.0), "0");
        assert_eq!(format_tick(&0.5), "0.5");
        assert_eq!(format_tick(&1.25), "1.25");
        assert_eq!(format_tick(&-90.0), "-90");
        assert_eq!(format_tick(&0.0125), "0.0125");
        assert_eq!(format_log_tick(&1000.0), "1k");
        assert_eq!(format_log_tick(&0.1), "0.1");
    }
}
