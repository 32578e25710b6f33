//! How a plot is drawn with `plotters`: the embedded fonts registered with
//! its `ab_glyph` backend (so no system font is ever looked up), the RGB
//! buffer it draws into, the chart around the data (title, axes, ticks,
//! grid) and the legend, and the data strokes and markers in pixels.
//!
//! Curves are clipped to the plot area here (Liang-Barsky), as `plotters`
//! does not clip what is drawn on the root area; widths are whole pixels, as
//! `plotters` strokes them.

use super::{Axis, Frame, LineStyle, Marker, Scale};
use crate::client::render::{Image, RenderError, Rgb};
use plotters::backend::BitMapBackend;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::element::{DashedPathElement, DottedPathElement};
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::sync::OnceLock;

/// Ink of the Pareto front and its labels.
pub(crate) const FRONT_INK: Rgb = [40, 40, 40];

/// The font family name under which the embedded DejaVu Sans is registered
/// with `plotters`.
pub(crate) const FONT: &str = "sans-serif";

/// Registers the embedded fonts with `plotters` (once per process).
pub(crate) fn register_fonts() -> Result<(), RenderError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            crate::client::render::text::REGULAR_BYTES,
        )
        .is_ok()
            && plotters::style::register_font(
                FONT,
                FontStyle::Bold,
                crate::client::render::text::BOLD_BYTES,
            )
            .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(RenderError::Plot(
            "the embedded DejaVu font cannot be read by plotters".into(),
        ))
    }
}

/// Draws with `plotters` on a `width` x `height` image of `background`.
pub(crate) fn draw_rgb<T>(
    width: u32,
    height: u32,
    background: Rgb,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<T, RenderError>,
) -> Result<(Image, T), RenderError> {
    let mut img = Image::new(width, height, background)?;
    let out = draw_over(&mut img, draw)?;
    Ok((img, out))
}

/// Draws with `plotters` over `img` (through an RGB buffer that `plotters`
/// owns while it draws).
pub(crate) fn draw_over<T>(
    img: &mut Image,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<T, RenderError>,
) -> Result<T, RenderError> {
    register_fonts()?;
    let (width, height) = (img.width(), img.height());
    let mut buf = img.to_rgb_bytes();
    let out = {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        let out = draw(&root)?;
        root.present().map_err(chart_err)?;
        out
    };
    *img = Image::from_rgb_bytes(width, height, &buf)?;
    Ok(out)
}

/// A `plotters` drawing failure as a render error.
pub(crate) fn chart_err<E: std::error::Error + Send + Sync + 'static>(
    e: DrawingAreaErrorKind<E>,
) -> RenderError {
    RenderError::Chart {
        source: Box::new(e),
    }
}

pub(crate) fn rgb(c: Rgb) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

const INK: Rgb = [45, 45, 45];
const GRID: Rgb = [228, 230, 234];
const GRID_MINOR: Rgb = [242, 243, 245];
const TICK_SIZE: f64 = 13.0;
const TITLE_SIZE: f64 = 17.0;
const AXIS_TITLE_SIZE: f64 = 14.0;
const LEGEND_SIZE: f64 = 13.0;

/// Tick label on a linear axis: six significant digits at most, a true minus
/// sign, scientific notation for very large or small magnitudes.
pub(crate) fn linear_label(v: f64) -> String {
    let v: f64 = format!("{v:.5e}").parse().unwrap_or(v);
    let s = if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-3) {
        format!("{v:e}")
    } else {
        format!("{v}")
    };
    s.replace('-', "\u{2212}")
}

/// Tick label on a log axis: decades only (plain between 0.001 and 1000,
/// else 10 with a superscript exponent); the ticks between are unlabelled.
pub(crate) fn log_label(v: f64) -> String {
    let k = v.log10();
    if (k - k.round()).abs() > 1e-6 {
        return String::new();
    }
    let k = k.round() as i32;
    if (-3..=3).contains(&k) {
        linear_label(10f64.powi(k))
    } else {
        const DIGITS: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
        let mut s = String::from("10");
        if k < 0 {
            s.push('⁻');
        }
        s.extend(
            k.unsigned_abs()
                .to_string()
                .chars()
                .map(|c| DIGITS[c.to_digit(10).unwrap_or(0) as usize]),
        );
        s
    }
}

fn label_of(scale: Scale) -> fn(f64) -> String {
    match scale {
        Scale::Linear => linear_label,
        Scale::Log10 => log_label,
    }
}

/// How a legend entry shows its series.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Swatch {
    /// A short stroke in the series' pattern and width, px.
    Line(LineStyle, f64),
    /// The group's marker.
    Marker(Marker),
}

/// One row of the legend: its label, colour and swatch.
pub(crate) struct LegendEntry {
    pub(crate) label: String,
    pub(crate) colour: Rgb,
    pub(crate) swatch: Swatch,
}

/// What the chart around the data shows.
pub(crate) struct ChartSpec<'a> {
    pub(crate) title: &'a str,
    pub(crate) x: &'a Axis,
    pub(crate) y: &'a Axis,
    pub(crate) x_range: (f64, f64),
    pub(crate) y_range: (f64, f64),
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) legend: Vec<LegendEntry>,
}

/// Draws title, axes, grid and legend on `root` and returns where the data
/// goes. The four scale combinations are the four coordinate types of
/// `plotters`; they share [`draw_chart`].
pub(crate) fn chart(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    s: &ChartSpec<'_>,
) -> Result<Frame, RenderError> {
    // A log range opened by a hair so that rounding in log10 does not drop
    // its end decades from the ticks; the frame keeps the exact range.
    let open = |(lo, hi): (f64, f64), scale| match scale {
        Scale::Linear => (lo, hi),
        Scale::Log10 => (lo * (1.0 - 1e-12), hi * (1.0 + 1e-12)),
    };
    let (xl, xh) = open(s.x_range, s.x.scale);
    let (yl, yh) = open(s.y_range, s.y.scale);
    match (s.x.scale, s.y.scale) {
        (Scale::Linear, Scale::Linear) => draw_chart(root, s, xl..xh, yl..yh),
        (Scale::Linear, Scale::Log10) => draw_chart(root, s, xl..xh, (yl..yh).log_scale()),
        (Scale::Log10, Scale::Linear) => draw_chart(root, s, (xl..xh).log_scale(), yl..yh),
        (Scale::Log10, Scale::Log10) => {
            draw_chart(root, s, (xl..xh).log_scale(), (yl..yh).log_scale())
        }
    }
}

fn draw_chart<X, Y>(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    s: &ChartSpec<'_>,
    x: X,
    y: Y,
) -> Result<Frame, RenderError>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let legend: Vec<&LegendEntry> = s.legend.iter().filter(|e| !e.label.is_empty()).collect();
    let legend_font: TextStyle<'_> = (FONT, LEGEND_SIZE).into_font().into();
    let legend_w = legend
        .iter()
        .filter_map(|e| root.estimate_text_size(&e.label, &legend_font).ok())
        .map(|(w, _)| w)
        .max()
        .map_or(0, |w| w as i32 + 44);
    let (xf, yf) = (label_of(s.x.scale), label_of(s.y.scale));
    // Key points that should be 0 come out as rounding noise (1e-17).
    let noise = |a: &Axis, (lo, hi): (f64, f64)| match a.scale {
        Scale::Linear => 1e-9 * (hi - lo),
        Scale::Log10 => 0.0,
    };
    let (xspan, yspan) = (noise(s.x, s.x_range), noise(s.y, s.y_range));
    let snap = |v: f64, eps: f64| if v.abs() < eps { 0.0 } else { v };
    let tick_font = (FONT, TICK_SIZE).into_font().color(&rgb(INK));
    let mut builder = ChartBuilder::on(root);
    builder
        .margin_top(10)
        .margin_left(12)
        .margin_bottom(8)
        .margin_right(if legend_w > 0 { legend_w + 28 } else { 24 } as u32)
        .x_label_area_size(if s.x.title.is_empty() { 26 } else { 48 })
        .y_label_area_size(if s.y.title.is_empty() { 52 } else { 76 });
    if !s.title.is_empty() {
        builder.caption(
            s.title,
            (FONT, TITLE_SIZE, FontStyle::Bold)
                .into_font()
                .color(&RGBColor(25, 25, 25)),
        );
    }
    let mut ch = builder.build_cartesian_2d(x, y).map_err(chart_err)?;
    let (xn, yn) = ((s.width / 110).clamp(3, 10), (s.height / 70).clamp(3, 10));
    ch.configure_mesh()
        .x_labels(xn as usize)
        .y_labels(yn as usize)
        .x_label_formatter(&|v| xf(snap(*v, xspan)))
        .y_label_formatter(&|v| yf(snap(*v, yspan)))
        .x_desc(s.x.title.as_str())
        .y_desc(s.y.title.as_str())
        .label_style(tick_font)
        .axis_desc_style((FONT, AXIS_TITLE_SIZE).into_font().color(&rgb(INK)))
        .bold_line_style(rgb(GRID))
        .light_line_style(rgb(GRID_MINOR))
        .axis_style(RGBColor(120, 120, 120))
        .draw()
        .map_err(chart_err)?;
    let cs = ch.as_coord_spec();
    let (l, b) = cs.translate(&(s.x_range.0, s.y_range.0));
    let (r, t) = cs.translate(&(s.x_range.1, s.y_range.1));
    let frame = Frame {
        area: [l as i64, t as i64, r as i64, b as i64],
        x_range: s.x_range,
        y_range: s.y_range,
        x_scale: s.x.scale,
        y_scale: s.y.scale,
    };
    drop(ch);
    draw_legend(root, &legend, (r + 14, t), legend_w)?;
    Ok(frame)
}

/// The legend box with its top-left corner at `at` (px), `width` px wide:
/// one row per entry, a swatch drawn as the series is, then the label.
fn draw_legend(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    entries: &[&LegendEntry],
    at: (i32, i32),
    width: i32,
) -> Result<(), RenderError> {
    if entries.is_empty() {
        return Ok(());
    }
    const ROW: i32 = 21;
    let (x, y) = at;
    let corners = [(x, y), (x + width, y + ROW * entries.len() as i32 + 10)];
    root.draw(&Rectangle::new(corners, RGBColor(250, 250, 251).filled()))
        .map_err(chart_err)?;
    root.draw(&Rectangle::new(corners, RGBColor(205, 208, 214)))
        .map_err(chart_err)?;
    let font = (FONT, LEGEND_SIZE)
        .into_font()
        .color(&rgb(INK))
        .pos(Pos::new(HPos::Left, VPos::Center));
    for (k, e) in entries.iter().enumerate() {
        let cy = y + 5 + ROW * k as i32 + ROW / 2;
        match e.swatch {
            Swatch::Line(style, w) => draw_stroke(
                root,
                vec![(x + 8, cy), (x + 32, cy)],
                rgb(e.colour),
                w.max(1.5),
                style,
            )?,
            Swatch::Marker(m) => draw_marker(root, (x + 20, cy), m, 4.5, rgb(e.colour))?,
        }
        root.draw(&Text::new(e.label.as_str(), (x + 38, cy), font.clone()))
            .map_err(chart_err)?;
    }
    Ok(())
}

/// Stroke width in whole pixels (plotters strokes integer widths).
fn stroke_px(width: f64) -> u32 {
    width.round().max(1.0) as u32
}

/// Radius of the dots of a dotted line of `width` px.
fn dot_px(width: f64) -> i32 {
    (width * 0.5).round().max(1.0) as i32
}

/// Strokes the pixel path `pts` in one of the patterns.
pub(crate) fn draw_stroke(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    pts: Vec<(i32, i32)>,
    colour: RGBColor,
    width: f64,
    style: LineStyle,
) -> Result<(), RenderError> {
    let st = colour.stroke_width(stroke_px(width));
    match style {
        LineStyle::Solid => root.draw(&PathElement::new(pts, st)),
        LineStyle::Dashed => root.draw(&DashedPathElement::new(pts, 8, 5, st)),
        LineStyle::Dotted => {
            let r = dot_px(width);
            root.draw(&DottedPathElement::new(pts, 0, 5, move |c| {
                Circle::new(c, r, colour.filled())
            }))
        }
    }
    .map_err(chart_err)
}

/// Clips the segment `a`-`b` (px) to the frame's area (Liang-Barsky).
fn clip_segment(f: &Frame, a: [f64; 2], b: [f64; 2]) -> Option<([f64; 2], [f64; 2])> {
    let [l, t, r, bt] = f.area.map(|v| v as f64);
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let (mut u0, mut u1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a[0] - l),
        (dx, r - a[0]),
        (-dy, a[1] - t),
        (dy, bt - a[1]),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let u = q / p;
            if p < 0.0 {
                u0 = u0.max(u);
            } else {
                u1 = u1.min(u);
            }
        }
    }
    (u0 <= u1).then(|| {
        (
            [a[0] + u0 * dx, a[1] + u0 * dy],
            [a[0] + u1 * dx, a[1] + u1 * dy],
        )
    })
}

/// The visible runs of a polyline of data points: mapped to pixels, clipped
/// to the area, broken where a point cannot be shown.
fn visible_runs(f: &Frame, points: &[[f64; 2]]) -> Vec<Vec<(i32, i32)>> {
    let px = |p: [f64; 2]| (p[0].round() as i32, p[1].round() as i32);
    let mut runs: Vec<Vec<(i32, i32)>> = Vec::new();
    let mut current: Vec<(i32, i32)> = Vec::new();
    let ok = |p: &[f64; 2]| p[0].is_finite() && p[1].is_finite();
    for w in points.windows(2) {
        let (a, b) = (f.to_px(w[0]), f.to_px(w[1]));
        let seg = (ok(&a) && ok(&b)).then(|| clip_segment(f, a, b)).flatten();
        match seg {
            Some((ca, cb)) => {
                if current.last() != Some(&px(ca)) {
                    if current.len() > 1 {
                        runs.push(std::mem::take(&mut current));
                    }
                    current.clear();
                    current.push(px(ca));
                }
                current.push(px(cb));
                // Leaving the area ends the run.
                if cb != b {
                    runs.push(std::mem::take(&mut current));
                }
            }
            None => {
                if current.len() > 1 {
                    runs.push(std::mem::take(&mut current));
                }
                current.clear();
            }
        }
    }
    if current.len() > 1 {
        runs.push(current);
    }
    runs
}

/// Draws a data polyline on `root` through `f`, clipped to the area.
pub(crate) fn draw_polyline(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    f: &Frame,
    points: &[[f64; 2]],
    colour: Rgb,
    width: f64,
    style: LineStyle,
) -> Result<(), RenderError> {
    for run in visible_runs(f, points) {
        draw_stroke(root, run, rgb(colour), width, style)?;
    }
    Ok(())
}

/// Refuses a plot area too small to show anything.
pub(crate) fn check_area(f: &Frame, width: u32, height: u32) -> Result<(), RenderError> {
    if f.area[2] - f.area[0] < 40 || f.area[3] - f.area[1] < 40 {
        return Err(RenderError::Plot(format!(
            "image {width} x {height} px is too small for the plot"
        )));
    }
    Ok(())
}

/// Draws the marker of radius `r` px at pixel `c`, with a thin white
/// outline.
pub(crate) fn draw_marker(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    c: (i32, i32),
    m: Marker,
    r: f64,
    colour: RGBColor,
) -> Result<(), RenderError> {
    let at = |pts: Vec<(i32, i32)>| -> Vec<(i32, i32)> {
        pts.into_iter().map(|(x, y)| (c.0 + x, c.1 + y)).collect()
    };
    root.draw(&Polygon::new(at(m.outline(r + 1.2)), WHITE.filled()))
        .map_err(chart_err)?;
    root.draw(&Polygon::new(at(m.outline(r)), colour.filled()))
        .map_err(chart_err)
}
