//! Line plots (forces over time) and scatter plots with a Pareto front
//! (error versus time), drawn to an [`Image`].
//!
//! A plot maps data (x, y) to pixels through its [`Frame`]: on a linear axis
//! `px = x0 + (x - lo) / (hi - lo) (x1 - x0)`, on a logarithmic axis the same
//! with `log10` of the values; y grows upwards. Ranges not given are taken
//! from the data (finite values; positive ones on log axes) and widened to
//! nice ticks (whole decades on log axes). Points that cannot be shown (NaN,
//! non-positive on a log axis) break the line.

use super::draw::{self, Dash, fill_rect, polyline, stroke_rect};
use super::text::{HAlign, TextStyle, VAlign, draw_text, draw_text_vertical, measure};
use super::{Image, RenderError, Rgb, ticks};

/// Axis scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Scale {
    /// Linear.
    #[default]
    Linear,
    /// Base-10 logarithmic (values must be > 0).
    Log10,
}

/// An axis: title (with unit), scale, and an optional fixed range.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// Title, e.g. "time (s)".
    pub title: String,
    /// Scale.
    pub scale: Scale,
    /// Fixed range (lo, hi); taken from the data when `None`.
    pub range: Option<(f64, f64)>,
}

impl Axis {
    /// A linear axis with an automatic range.
    pub fn linear(title: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            scale: Scale::Linear,
            range: None,
        }
    }

    /// A logarithmic axis with an automatic range.
    pub fn log(title: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            scale: Scale::Log10,
            range: None,
        }
    }

    /// The same axis with a fixed range.
    pub fn with_range(mut self, lo: f64, hi: f64) -> Self {
        self.range = Some((lo, hi));
        self
    }
}

/// Line pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LineStyle {
    /// Solid.
    #[default]
    Solid,
    /// Dashes of 8 px with 5 px gaps.
    Dashed,
    /// Dots of 2 px with 3 px gaps.
    Dotted,
}

impl LineStyle {
    fn dash(self) -> Option<Dash> {
        match self {
            LineStyle::Solid => None,
            LineStyle::Dashed => Some(Dash { on: 8.0, off: 5.0 }),
            LineStyle::Dotted => Some(Dash { on: 2.0, off: 3.0 }),
        }
    }
}

/// A curve of a line plot.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry (an empty label is left out of the legend).
    pub label: String,
    /// Points (x, y) in drawing order.
    pub points: Vec<[f64; 2]>,
    /// Colour.
    pub colour: Rgb,
    /// Line width, px.
    pub width: f64,
    /// Pattern.
    pub style: LineStyle,
}

impl Series {
    /// A solid 2 px series.
    pub fn new(label: impl Into<String>, points: Vec<[f64; 2]>, colour: Rgb) -> Self {
        Self {
            label: label.into(),
            points,
            colour,
            width: 2.0,
            style: LineStyle::Solid,
        }
    }

    /// The same series with another width, px.
    pub fn width(mut self, width: f64) -> Self {
        self.width = width;
        self
    }

    /// The same series with another pattern.
    pub fn style(mut self, style: LineStyle) -> Self {
        self.style = style;
        self
    }
}

/// A horizontal reference line (a threshold), drawn dashed across the plot.
#[derive(Debug, Clone, PartialEq)]
pub struct HLine {
    /// Its y value.
    pub y: f64,
    /// Label, written at its right end above the line.
    pub label: String,
    /// Colour.
    pub colour: Rgb,
}

/// The 10 categorical colours of Tableau (blue, orange, green, red, ...),
/// cycled.
pub fn palette(i: usize) -> Rgb {
    colorous::TABLEAU10[i % 10].as_array()
}

/// Where the data goes in the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Plot area, px: left, top, right, bottom (exclusive).
    pub area: [i64; 4],
    /// Shown x range.
    pub x_range: (f64, f64),
    /// Shown y range.
    pub y_range: (f64, f64),
    /// x scale.
    pub x_scale: Scale,
    /// y scale.
    pub y_scale: Scale,
}

fn fwd(scale: Scale, v: f64) -> f64 {
    match scale {
        Scale::Linear => v,
        Scale::Log10 => {
            if v > 0.0 {
                v.log10()
            } else {
                f64::NAN
            }
        }
    }
}

impl Frame {
    /// Pixel position (x right, y down) of data point `p`; NaN components
    /// when it cannot be shown on a log axis.
    pub fn to_px(&self, p: [f64; 2]) -> [f64; 2] {
        let [l, t, r, b] = self.area.map(|v| v as f64);
        let fx = (fwd(self.x_scale, p[0]) - fwd(self.x_scale, self.x_range.0))
            / (fwd(self.x_scale, self.x_range.1) - fwd(self.x_scale, self.x_range.0));
        let fy = (fwd(self.y_scale, p[1]) - fwd(self.y_scale, self.y_range.0))
            / (fwd(self.y_scale, self.y_range.1) - fwd(self.y_scale, self.y_range.0));
        [l + fx * (r - l), b - fy * (b - t)]
    }
}

/// Data range for an axis: the fixed one, or the data's widened to ticks.
fn axis_range(
    axis: &Axis,
    values: impl Iterator<Item = f64>,
    which: &str,
) -> Result<(f64, f64), RenderError> {
    if let Some((lo, hi)) = axis.range {
        let ok = lo.is_finite()
            && hi.is_finite()
            && hi > lo
            && (axis.scale == Scale::Linear || lo > 0.0);
        if !ok {
            return Err(RenderError::Plot(format!(
                "{which} axis range ({lo}, {hi}) cannot be shown"
            )));
        }
        return Ok((lo, hi));
    }
    let usable: Vec<f64> = values
        .filter(|v| v.is_finite() && (axis.scale == Scale::Linear || *v > 0.0))
        .collect();
    let (lo, hi) = usable
        .iter()
        .fold(None, |acc: Option<(f64, f64)>, &v| {
            Some(acc.map_or((v, v), |(a, b)| (a.min(v), b.max(v))))
        })
        .ok_or_else(|| RenderError::Plot(format!("no {which} value can be shown")))?;
    Ok(match axis.scale {
        Scale::Linear => ticks::nice_range(lo, hi, 6),
        Scale::Log10 => {
            let (a, b) = (lo.log10().floor(), hi.log10().ceil());
            let b = if b <= a { a + 1.0 } else { b };
            (10f64.powf(a), 10f64.powf(b))
        }
    })
}

fn axis_ticks(scale: Scale, range: (f64, f64), target: usize) -> Vec<ticks::Tick> {
    match scale {
        Scale::Linear => ticks::linear(range.0, range.1, target).0,
        Scale::Log10 => ticks::log10(range.0, range.1),
    }
}

const INK: Rgb = [45, 45, 45];
const GRID: Rgb = [228, 230, 234];
const GRID_MINOR: Rgb = [242, 243, 245];

/// Common layout and decoration of both kinds of plot.
struct Canvas {
    img: Image,
    frame: Frame,
    x_ticks: Vec<ticks::Tick>,
    y_ticks: Vec<ticks::Tick>,
}

/// A legend entry: label, colour, and how to draw the swatch.
enum Swatch {
    Line(LineStyle, f64),
    Marker(Marker),
}

struct LegendEntry {
    label: String,
    colour: Rgb,
    swatch: Swatch,
}

const TICK_SIZE: f32 = 13.0;
const TITLE_SIZE: f32 = 17.0;
const AXIS_TITLE_SIZE: f32 = 14.0;
const LEGEND_SIZE: f32 = 13.0;

impl Canvas {
    fn new(
        width: u32,
        height: u32,
        title: &str,
        x: &Axis,
        y: &Axis,
        x_range: (f64, f64),
        y_range: (f64, f64),
        legend: &[LegendEntry],
    ) -> Result<Self, RenderError> {
        let img = Image::new(width, height, [255; 3])?;
        let tick_style = TextStyle::new(TICK_SIZE);
        let x_ticks = axis_ticks(x.scale, x_range, (width / 110).clamp(3, 10) as usize);
        let y_ticks = axis_ticks(y.scale, y_range, (height / 70).clamp(3, 10) as usize);
        let label_w = y_ticks
            .iter()
            .map(|t| measure(&t.label, &tick_style).width)
            .fold(0.0, f32::max);
        let line_h = measure("0", &tick_style);
        let line_h = line_h.ascent + line_h.descent;
        let axis_h = {
            let e = measure("Ag", &TextStyle::new(AXIS_TITLE_SIZE));
            e.ascent + e.descent
        };
        let title_h = if title.is_empty() {
            12.0
        } else {
            let e = measure(title, &TextStyle::new(TITLE_SIZE).bold());
            e.ascent + e.descent + 20.0
        };
        let legend_w = legend
            .iter()
            .filter(|e| !e.label.is_empty())
            .map(|e| measure(&e.label, &TextStyle::new(LEGEND_SIZE)).width + 44.0)
            .fold(0.0f32, f32::max);
        let left = (12.0
            + if y.title.is_empty() {
                0.0
            } else {
                axis_h + 10.0
            }
            + label_w
            + 10.0)
            .ceil() as i64;
        let right = if legend_w > 0.0 {
            (legend_w + 28.0) as i64
        } else {
            24
        };
        let bottom = (8.0
            + line_h
            + 10.0
            + if x.title.is_empty() {
                0.0
            } else {
                axis_h + 10.0
            })
        .ceil() as i64;
        let top = title_h.ceil() as i64;
        let area = [left, top, width as i64 - right, height as i64 - bottom];
        if area[2] - area[0] < 40 || area[3] - area[1] < 40 {
            return Err(RenderError::Plot(format!(
                "image {width} x {height} px is too small for the plot"
            )));
        }
        let frame = Frame {
            area,
            x_range,
            y_range,
            x_scale: x.scale,
            y_scale: y.scale,
        };
        let mut c = Self {
            img,
            frame,
            x_ticks,
            y_ticks,
        };
        c.decorate(title, x, y, legend);
        Ok(c)
    }

    /// Grid, axes box, ticks, labels, titles and legend; data is drawn after
    /// (clipped to the area) and the box redrawn over it.
    fn decorate(&mut self, title: &str, x: &Axis, y: &Axis, legend: &[LegendEntry]) {
        let [l, t, r, b] = self.frame.area;
        let img = &mut self.img;
        for tk in &self.x_ticks {
            let px = self.frame.to_px([tk.value, self.frame.y_range.0])[0].round() as i64;
            let colour = if tk.label.is_empty() {
                GRID_MINOR
            } else {
                GRID
            };
            fill_rect(img, px, t, px + 1, b, colour);
        }
        for tk in &self.y_ticks {
            let py = self.frame.to_px([self.frame.x_range.0, tk.value])[1].round() as i64;
            let colour = if tk.label.is_empty() {
                GRID_MINOR
            } else {
                GRID
            };
            fill_rect(img, l, py, r, py + 1, colour);
        }
        let tick_style = TextStyle::new(TICK_SIZE).colour(INK);
        for tk in &self.x_ticks {
            let px = self.frame.to_px([tk.value, self.frame.y_range.0])[0].round() as i64;
            let len = if tk.label.is_empty() { 3 } else { 6 };
            fill_rect(img, px, b, px + 1, b + len, INK);
            if !tk.label.is_empty() {
                let st = tick_style.align(HAlign::Center, VAlign::Top);
                draw_text(img, &tk.label, px as f32 + 0.5, (b + 9) as f32, &st);
            }
        }
        for tk in &self.y_ticks {
            let py = self.frame.to_px([self.frame.x_range.0, tk.value])[1].round() as i64;
            let len = if tk.label.is_empty() { 3 } else { 6 };
            fill_rect(img, l - len, py, l, py + 1, INK);
            if !tk.label.is_empty() {
                let st = tick_style.align(HAlign::Right, VAlign::Middle);
                draw_text(img, &tk.label, (l - 9) as f32, py as f32 + 0.5, &st);
            }
        }
        let axis_style = TextStyle::new(AXIS_TITLE_SIZE).colour(INK);
        if !x.title.is_empty() {
            let st = axis_style.align(HAlign::Center, VAlign::Bottom);
            draw_text(
                img,
                &x.title,
                0.5 * (l + r) as f32,
                img.height() as f32 - 8.0,
                &st,
            );
        }
        if !y.title.is_empty() {
            let st = axis_style.align(HAlign::Center, VAlign::Top);
            draw_text_vertical(img, &y.title, 10.0, 0.5 * (t + b) as f32, &st);
        }
        if !title.is_empty() {
            let st = TextStyle::new(TITLE_SIZE)
                .bold()
                .colour([25, 25, 25])
                .align(HAlign::Center, VAlign::Top);
            draw_text(img, title, 0.5 * (l + r) as f32, 10.0, &st);
        }
        // Legend right of the plot area, top-aligned.
        let entries: Vec<&LegendEntry> = legend.iter().filter(|e| !e.label.is_empty()).collect();
        if !entries.is_empty() {
            let st = TextStyle::new(LEGEND_SIZE)
                .colour(INK)
                .align(HAlign::Left, VAlign::Middle);
            let row = 21.0;
            let lx = r as f64 + 14.0;
            let w = entries
                .iter()
                .map(|e| measure(&e.label, &st).width)
                .fold(0.0f32, f32::max) as f64
                + 44.0;
            let h = row * entries.len() as f64 + 10.0;
            fill_rect(
                img,
                lx as i64,
                t,
                (lx + w) as i64,
                t + h as i64,
                [250, 250, 251],
            );
            stroke_rect(
                img,
                lx as i64,
                t,
                (lx + w) as i64,
                t + h as i64,
                [205, 208, 214],
            );
            for (k, e) in entries.iter().enumerate() {
                let cy = t as f64 + 5.0 + row * (k as f64 + 0.5);
                match e.swatch {
                    Swatch::Line(style, width) => {
                        polyline(
                            img,
                            &[[lx + 8.0, cy], [lx + 32.0, cy]],
                            width.max(1.5),
                            e.colour,
                            style.dash(),
                        );
                    }
                    Swatch::Marker(m) => m.draw(img, [lx + 20.0, cy], 4.5, e.colour),
                }
                draw_text(img, &e.label, (lx + 38.0) as f32, cy as f32, &st);
            }
        }
    }

    /// An image of the plot area to draw data into (white with the grid), to
    /// be put back with [`Canvas::finish`].
    fn area_image(&self) -> Image {
        let [l, t, r, b] = self.frame.area;
        let mut sub = Image::new((r - l) as u32, (b - t) as u32, [255; 3])
            .unwrap_or_else(|_| self.img.clone());
        for y in 0..sub.height() as i64 {
            for x in 0..sub.width() as i64 {
                if let Some(p) = self.img.get((l + x) as u32, (t + y) as u32) {
                    sub.put(x, y, p);
                }
            }
        }
        sub
    }

    /// Frame for drawing into the area image (its origin at the area's corner).
    fn local_frame(&self) -> Frame {
        let [l, t, r, b] = self.frame.area;
        Frame {
            area: [0, 0, r - l, b - t],
            ..self.frame
        }
    }

    fn finish(mut self, area: Image) -> Image {
        let [l, t, r, b] = self.frame.area;
        self.img.blit(&area, l, t);
        stroke_rect(&mut self.img, l - 1, t - 1, r + 1, b + 1, [120, 120, 120]);
        self.img
    }
}

/// A line plot.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Title above the plot.
    pub title: String,
    /// Horizontal axis.
    pub x: Axis,
    /// Vertical axis.
    pub y: Axis,
    /// Curves.
    pub series: Vec<Series>,
    /// Horizontal reference lines.
    pub hlines: Vec<HLine>,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
}

impl LinePlot {
    /// An empty 900 x 500 px plot.
    pub fn new(title: impl Into<String>, x: Axis, y: Axis) -> Self {
        Self {
            title: title.into(),
            x,
            y,
            series: Vec::new(),
            hlines: Vec::new(),
            width: 900,
            height: 500,
        }
    }

    /// Adds a curve.
    pub fn add(&mut self, s: Series) -> &mut Self {
        self.series.push(s);
        self
    }

    /// Adds a dashed horizontal line at `y` (a threshold).
    pub fn threshold(&mut self, y: f64, label: impl Into<String>, colour: Rgb) -> &mut Self {
        self.hlines.push(HLine {
            y,
            label: label.into(),
            colour,
        });
        self
    }

    fn legend(&self) -> Vec<LegendEntry> {
        self.series
            .iter()
            .map(|s| LegendEntry {
                label: s.label.clone(),
                colour: s.colour,
                swatch: Swatch::Line(s.style, s.width),
            })
            .collect()
    }

    /// The frame the plot will use (where data lands in the image).
    pub fn frame(&self) -> Result<Frame, RenderError> {
        Ok(self.canvas()?.frame)
    }

    fn canvas(&self) -> Result<Canvas, RenderError> {
        let xs = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p[0]));
        let ys = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p[1]))
            .chain(self.hlines.iter().map(|h| h.y));
        let xr = axis_range(&self.x, xs, "x")?;
        let yr = axis_range(&self.y, ys, "y")?;
        Canvas::new(
            self.width,
            self.height,
            &self.title,
            &self.x,
            &self.y,
            xr,
            yr,
            &self.legend(),
        )
    }

    /// Draws the plot.
    pub fn render(&self) -> Result<Image, RenderError> {
        let canvas = self.canvas()?;
        let mut area = canvas.area_image();
        let f = canvas.local_frame();
        for h in &self.hlines {
            let py = f.to_px([f.x_range.0, h.y])[1];
            if !py.is_finite() {
                continue;
            }
            let aw = area.width() as f64;
            polyline(
                &mut area,
                &[[0.0, py], [aw, py]],
                1.6,
                h.colour,
                LineStyle::Dashed.dash(),
            );
            if !h.label.is_empty() {
                let st = TextStyle::new(12.0)
                    .colour(h.colour)
                    .align(HAlign::Right, VAlign::Bottom);
                draw_text(&mut area, &h.label, aw as f32 - 6.0, py as f32 - 3.0, &st);
            }
        }
        for s in &self.series {
            let pts: Vec<[f64; 2]> = s.points.iter().map(|&p| f.to_px(p)).collect();
            polyline(&mut area, &pts, s.width, s.colour, s.style.dash());
        }
        Ok(canvas.finish(area))
    }

    /// Draws the plot and writes it as a PNG.
    pub fn save_png(&self, path: impl AsRef<std::path::Path>) -> Result<(), RenderError> {
        self.render()?.save_png(path)
    }
}

/// Forces of one instrument over time, for [`force_plot`].
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentForces {
    /// Instrument name, e.g. "left".
    pub name: String,
    /// Sample times, s.
    pub time: Vec<f64>,
    /// Forces (x, y, z), N, one per time.
    pub force: Vec<[f64; 3]>,
}

/// The force plot of a run: for each instrument |F| (thick) and, when
/// `components`, Fx, Fy, Fz (thin; instrument i uses palette colours 4i..);
/// an optional safety threshold (N) as a dashed red line.
pub fn force_plot(
    title: &str,
    instruments: &[InstrumentForces],
    components: bool,
    threshold: Option<f64>,
) -> LinePlot {
    let mut plot = LinePlot::new(title, Axis::linear("time (s)"), Axis::linear("force (N)"));
    // Per instrument: a base colour for |F| and three for the components.
    const SETS: [[Rgb; 4]; 2] = [
        [
            [31, 87, 160],
            [94, 153, 221],
            [38, 160, 140],
            [150, 110, 200],
        ],
        [
            [200, 82, 20],
            [240, 150, 70],
            [190, 150, 30],
            [200, 90, 140],
        ],
    ];
    for (i, ins) in instruments.iter().enumerate() {
        let set = SETS[i % 2];
        let n = ins.time.len().min(ins.force.len());
        let mag: Vec<[f64; 2]> = (0..n)
            .map(|k| {
                let f = ins.force[k];
                [
                    ins.time[k],
                    (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt(),
                ]
            })
            .collect();
        if components {
            for (c, name) in ["Fx", "Fy", "Fz"].iter().enumerate() {
                let pts = (0..n).map(|k| [ins.time[k], ins.force[k][c]]).collect();
                let style = [LineStyle::Solid, LineStyle::Dashed, LineStyle::Dotted][c];
                plot.add(
                    Series::new(format!("{} {name}", ins.name), pts, set[c + 1])
                        .width(1.3)
                        .style(style),
                );
            }
        }
        plot.add(Series::new(format!("{} |F|", ins.name), mag, set[0]).width(2.4));
    }
    if let Some(t) = threshold {
        plot.threshold(
            t,
            format!("limit {} N", ticks::format_value(t, t.abs() / 10.0)),
            [200, 30, 30],
        );
    }
    plot
}

/// A scatter marker shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Marker {
    /// Disc.
    #[default]
    Circle,
    /// Square.
    Square,
    /// Diamond.
    Diamond,
    /// Upward triangle.
    Triangle,
}

impl Marker {
    /// Draws the marker of radius `r` px at `c`, with a thin white outline.
    pub fn draw(self, img: &mut Image, c: [f64; 2], r: f64, colour: Rgb) {
        if !(c[0].is_finite() && c[1].is_finite()) {
            return;
        }
        let shape = |r: f64| -> Vec<[f64; 2]> {
            match self {
                Marker::Circle => Vec::new(),
                Marker::Square => {
                    let h = r * 0.85;
                    vec![
                        [c[0] - h, c[1] - h],
                        [c[0] + h, c[1] - h],
                        [c[0] + h, c[1] + h],
                        [c[0] - h, c[1] + h],
                    ]
                }
                Marker::Diamond => {
                    let h = r * 1.2;
                    vec![
                        [c[0], c[1] - h],
                        [c[0] + h, c[1]],
                        [c[0], c[1] + h],
                        [c[0] - h, c[1]],
                    ]
                }
                Marker::Triangle => {
                    let h = r * 1.25;
                    vec![
                        [c[0], c[1] - h],
                        [c[0] + h * 0.95, c[1] + h * 0.65],
                        [c[0] - h * 0.95, c[1] + h * 0.65],
                    ]
                }
            }
        };
        for (rr, col) in [(r + 1.2, [255, 255, 255]), (r, colour)] {
            match self {
                Marker::Circle => draw::disc(img, c, rr, col),
                _ => draw::fill_polygon(img, &shape(rr), col),
            }
        }
    }
}

/// A group of scatter points sharing colour and marker.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterGroup {
    /// Legend entry.
    pub label: String,
    /// Points (x, y).
    pub points: Vec<[f64; 2]>,
    /// Optional per-point labels (empty, or one per point), written next to
    /// points on the Pareto front.
    pub point_labels: Vec<String>,
    /// Colour.
    pub colour: Rgb,
    /// Marker.
    pub marker: Marker,
}

/// A scatter plot, optionally with the Pareto front of all its points
/// (minimising both x and y) drawn as a staircase.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterPlot {
    /// Title.
    pub title: String,
    /// Horizontal axis.
    pub x: Axis,
    /// Vertical axis.
    pub y: Axis,
    /// Groups.
    pub groups: Vec<ScatterGroup>,
    /// Whether to draw the Pareto front.
    pub pareto: bool,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
}

/// Indices of the points not dominated by any other (a point dominates
/// another when it is no larger in both coordinates and smaller in one),
/// sorted by increasing x. Non-finite points are ignored; of identical points
/// the first is kept.
pub fn pareto_front(points: &[[f64; 2]]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i][0].is_finite() && points[i][1].is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        points[a][0]
            .total_cmp(&points[b][0])
            .then(points[a][1].total_cmp(&points[b][1]))
            .then(a.cmp(&b))
    });
    let mut front = Vec::new();
    let mut best_y = f64::INFINITY;
    for i in idx {
        if points[i][1] < best_y {
            best_y = points[i][1];
            front.push(i);
        }
    }
    front
}

impl ScatterPlot {
    /// An empty 800 x 560 px scatter plot with the Pareto front shown.
    pub fn new(title: impl Into<String>, x: Axis, y: Axis) -> Self {
        Self {
            title: title.into(),
            x,
            y,
            groups: Vec::new(),
            pareto: true,
            width: 800,
            height: 560,
        }
    }

    /// Adds a group.
    pub fn add(&mut self, g: ScatterGroup) -> &mut Self {
        self.groups.push(g);
        self
    }

    fn canvas(&self) -> Result<Canvas, RenderError> {
        let xs = self
            .groups
            .iter()
            .flat_map(|g| g.points.iter().map(|p| p[0]));
        let ys = self
            .groups
            .iter()
            .flat_map(|g| g.points.iter().map(|p| p[1]));
        let xr = axis_range(&self.x, xs, "x")?;
        let yr = axis_range(&self.y, ys, "y")?;
        let mut legend: Vec<LegendEntry> = self
            .groups
            .iter()
            .map(|g| LegendEntry {
                label: g.label.clone(),
                colour: g.colour,
                swatch: Swatch::Marker(g.marker),
            })
            .collect();
        if self.pareto {
            legend.push(LegendEntry {
                label: "Pareto front".into(),
                colour: [40, 40, 40],
                swatch: Swatch::Line(LineStyle::Dashed, 1.5),
            });
        }
        Canvas::new(
            self.width,
            self.height,
            &self.title,
            &self.x,
            &self.y,
            xr,
            yr,
            &legend,
        )
    }

    /// The frame the plot will use.
    pub fn frame(&self) -> Result<Frame, RenderError> {
        Ok(self.canvas()?.frame)
    }

    /// Draws the plot.
    pub fn render(&self) -> Result<Image, RenderError> {
        let canvas = self.canvas()?;
        let mut area = canvas.area_image();
        let f = canvas.local_frame();
        // Only points that can be shown take part in the front.
        let all: Vec<(usize, usize, [f64; 2])> = self
            .groups
            .iter()
            .enumerate()
            .flat_map(|(gi, g)| g.points.iter().enumerate().map(move |(pi, &p)| (gi, pi, p)))
            .filter(|(_, _, p)| f.to_px(*p).iter().all(|v| v.is_finite()))
            .collect();
        let front: Vec<usize> = if self.pareto {
            pareto_front(&all.iter().map(|a| a.2).collect::<Vec<_>>())
        } else {
            Vec::new()
        };
        if front.len() > 1 {
            let mut stair = Vec::with_capacity(2 * front.len());
            for (k, &i) in front.iter().enumerate() {
                let p = all[i].2;
                if k > 0 {
                    let prev = all[front[k - 1]].2;
                    stair.push(f.to_px([p[0], prev[1]]));
                }
                stair.push(f.to_px(p));
            }
            polyline(
                &mut area,
                &stair,
                1.5,
                [40, 40, 40],
                LineStyle::Dashed.dash(),
            );
        }
        for g in &self.groups {
            for &p in &g.points {
                g.marker.draw(&mut area, f.to_px(p), 4.5, g.colour);
            }
        }
        for &i in &front {
            let (gi, pi, p) = all[i];
            let c = f.to_px(p);
            // Ring around front points.
            let mut ring = Vec::with_capacity(33);
            for k in 0..=32 {
                let a = k as f64 / 32.0 * std::f64::consts::TAU;
                ring.push([c[0] + 8.0 * a.cos(), c[1] + 8.0 * a.sin()]);
            }
            polyline(&mut area, &ring, 1.4, [40, 40, 40], None);
            if let Some(label) = self.groups[gi]
                .point_labels
                .get(pi)
                .filter(|l| !l.is_empty())
            {
                let st = TextStyle::new(12.0)
                    .colour([40, 40, 40])
                    .align(HAlign::Left, VAlign::Bottom);
                draw_text(
                    &mut area,
                    label,
                    (c[0] + 9.0) as f32,
                    (c[1] - 6.0) as f32,
                    &st,
                );
            }
        }
        Ok(canvas.finish(area))
    }

    /// Draws the plot and writes it as a PNG.
    pub fn save_png(&self, path: impl AsRef<std::path::Path>) -> Result<(), RenderError> {
        self.render()?.save_png(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn is_colour(img: &Image, x: f64, y: f64, c: Rgb, tol: i32) -> bool {
        img.get(x as u32, y as u32).is_some_and(|p| {
            p.iter()
                .zip(c)
                .all(|(a, b)| (*a as i32 - b as i32).abs() <= tol)
        })
    }

    #[test]
    fn a_known_line_lands_on_the_expected_pixels() {
        let red = [220, 20, 20];
        let mut plot = LinePlot::new(
            "y = 2x",
            Axis::linear("x").with_range(0.0, 1.0),
            Axis::linear("y").with_range(0.0, 2.0),
        );
        plot.add(Series::new("2x", vec![[0.0, 0.0], [1.0, 2.0]], red).width(3.0));
        let frame = plot.frame().unwrap();
        let img = plot.render().unwrap();
        for t in [0.2, 0.5, 0.8] {
            let p = frame.to_px([t, 2.0 * t]);
            assert!(
                is_colour(&img, p[0], p[1], red, 10),
                "curve missing at x = {t}"
            );
            // Well off the line: background (white or grid).
            let q = frame.to_px([t, 2.0 * t + 0.4]);
            assert!(
                !is_colour(&img, q[0], q[1], red, 60),
                "ink off the curve at x = {t}"
            );
        }
        // The frame maps corners of the range to the corners of the area.
        let [l, t, r, b] = frame.area.map(|v| v as f64);
        assert_eq!(frame.to_px([0.0, 0.0]), [l, b]);
        assert_eq!(frame.to_px([1.0, 2.0]), [r, t]);
    }

    #[test]
    fn threshold_line_is_dashed_at_its_value() {
        let mut plot = LinePlot::new(
            "",
            Axis::linear("t (s)").with_range(0.0, 1.0),
            Axis::linear("F (N)").with_range(0.0, 1.0),
        );
        plot.add(Series::new("", vec![[0.0, 0.1], [1.0, 0.1]], [0, 0, 255]));
        plot.threshold(0.5, "", [200, 30, 30]);
        let frame = plot.frame().unwrap();
        let img = plot.render().unwrap();
        let y = frame.to_px([0.0, 0.5])[1];
        let [l, _, r, _] = frame.area;
        let on = (l..r)
            .filter(|&x| is_colour(&img, x as f64, y, [200, 30, 30], 40))
            .count();
        let span = (r - l) as usize;
        assert!(
            on > span / 3 && on < span * 9 / 10,
            "dashed coverage {on} of {span}"
        );
    }

    #[test]
    fn out_of_range_data_is_clipped_to_the_area() {
        let blue = [0, 0, 255];
        let mut plot = LinePlot::new(
            "",
            Axis::linear("x").with_range(0.0, 1.0),
            Axis::linear("y").with_range(0.0, 1.0),
        );
        plot.add(Series::new("", vec![[-1.0, 0.5], [2.0, 0.5]], blue).width(4.0));
        let frame = plot.frame().unwrap();
        let img = plot.render().unwrap();
        let y = frame.to_px([0.0, 0.5])[1];
        assert!(is_colour(&img, (frame.area[0] + 5) as f64, y, blue, 10));
        assert!(!is_colour(&img, (frame.area[0] - 20) as f64, y, blue, 60));
    }

    #[test]
    fn pareto_front_of_known_points() {
        let pts = [
            [1.0, 5.0],
            [2.0, 3.0],
            [3.0, 4.0],
            [4.0, 1.0],
            [5.0, 1.0],
            [0.5, 9.0],
            [f64::NAN, 0.0],
        ];
        assert_eq!(pareto_front(&pts), vec![5, 0, 1, 3]);
        assert!(pareto_front(&[]).is_empty());
    }

    #[test]
    fn log_axes_place_decades_evenly() {
        let mut plot = ScatterPlot::new("", Axis::log("time (s)"), Axis::log("error"));
        plot.add(ScatterGroup {
            label: "a".into(),
            points: vec![[1e-3, 1e-1], [1e-1, 1e-3], [-1.0, 1.0]],
            point_labels: vec![],
            colour: [0, 0, 200],
            marker: Marker::Circle,
        });
        let f = plot.frame().unwrap();
        assert_eq!(f.x_range, (1e-3, 1e-1));
        let a = f.to_px([1e-3, 1e-2]);
        let b = f.to_px([1e-2, 1e-2]);
        let c = f.to_px([1e-1, 1e-2]);
        assert!(((b[0] - a[0]) - (c[0] - b[0])).abs() < 1e-9);
        assert!(f.to_px([-1.0, 1.0])[0].is_nan());
        let img = plot.render().unwrap();
        let p = f.to_px([1e-3, 1e-1]);
        assert!(is_colour(&img, p[0], p[1], [0, 0, 200], 30));
    }

    #[test]
    fn bad_plots_are_errors_not_panics() {
        let plot = LinePlot::new("", Axis::linear("x"), Axis::linear("y"));
        assert!(matches!(plot.render(), Err(RenderError::Plot(_))));
        let mut plot = LinePlot::new("", Axis::log("x").with_range(-1.0, 1.0), Axis::linear("y"));
        plot.add(Series::new("", vec![[1.0, 1.0]], [0; 3]));
        assert!(matches!(plot.render(), Err(RenderError::Plot(_))));
        let mut plot = LinePlot::new("", Axis::linear("x"), Axis::linear("y"));
        plot.width = 50;
        plot.add(Series::new("", vec![[1.0, 1.0], [2.0, 2.0]], [0; 3]));
        assert!(matches!(plot.render(), Err(RenderError::Plot(_))));
    }
}
