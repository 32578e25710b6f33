//! Line plots (forces over time) and scatter plots with a Pareto front
//! (error versus time), drawn with `plotters` into an [`Image`].
//!
//! This module says what a plot shows; [`chart`] draws it: `plotters` lays
//! out the chart (title, axes with their ticks and titles, the grid) and
//! draws into an RGB buffer, so the PNG and GIF writers of [`super`] stay.
//!
//! The data is placed in pixels through a [`Frame`] read back from the
//! chart: on a linear axis `px = x0 + (x - lo) / (hi - lo) (x1 - x0)`, on a
//! logarithmic axis the same with `log10` of the values; y grows upwards.
//! Ranges not given are taken from the data (finite values; positive ones on
//! log axes) and widened to whole ticks (whole decades on log axes). Points
//! that cannot be shown (NaN, non-positive on a log axis) break the line.

pub(crate) mod chart;

use super::{Image, RenderError, Rgb};
pub(crate) use chart::linear_label;
use chart::{
    ChartSpec, FONT, FRONT_INK, LegendEntry, Swatch, chart, chart_err, check_area, draw_marker,
    draw_polyline, draw_rgb, draw_stroke, rgb,
};
use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

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
    /// Dots 5 px apart.
    Dotted,
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
    /// Line width, px (drawn rounded to whole pixels, at least 1).
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
    /// Plot area, px: the pixels of (x lo, y hi) and (x hi, y lo) as left,
    /// top, right, bottom.
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

    /// Whether pixel position `p` lies inside the plot area.
    pub(crate) fn contains(&self, p: [f64; 2]) -> bool {
        let [l, t, r, b] = self.area.map(|v| v as f64);
        p[0] >= l && p[0] <= r && p[1] >= t && p[1] <= b
    }
}

/// `[lo, hi]` widened outwards to the ticks `plotters` puts on a linear axis
/// of about `target` intervals (an empty range is first opened around its
/// value).
pub fn nice_range(lo: f64, hi: f64, target: usize) -> (f64, f64) {
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        (lo - d, lo + d)
    };
    let keys = RangedCoordf64::from(lo..hi).key_points(target.max(1) + 1);
    let step = match keys.as_slice() {
        [a, b, ..] => b - a,
        _ => return (lo, hi),
    };
    let snap = |v: f64| (v / step).round() * step;
    let lo = if (lo / step - (lo / step).round()).abs() < 1e-9 {
        snap(lo)
    } else {
        (lo / step).floor() * step
    };
    let hi = if (hi / step - (hi / step).round()).abs() < 1e-9 {
        snap(hi)
    } else {
        (hi / step).ceil() * step
    };
    (lo, hi)
}

/// Data range for an axis: the fixed one, or the data's widened to ticks.
pub(crate) fn axis_range(
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
    let (lo, hi) = values
        .filter(|v| v.is_finite() && (axis.scale == Scale::Linear || *v > 0.0))
        .fold(None, |acc: Option<(f64, f64)>, v| {
            Some(acc.map_or((v, v), |(a, b)| (a.min(v), b.max(v))))
        })
        .ok_or_else(|| RenderError::Plot(format!("no {which} value can be shown")))?;
    Ok(match axis.scale {
        Scale::Linear => nice_range(lo, hi, 6),
        Scale::Log10 => {
            let (a, b) = (lo.log10().floor(), hi.log10().ceil());
            let b = if b <= a { a + 1.0 } else { b };
            (10f64.powf(a), 10f64.powf(b))
        }
    })
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

    fn spec(&self) -> Result<ChartSpec<'_>, RenderError> {
        let xs = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p[0]));
        let ys = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p[1]))
            .chain(self.hlines.iter().map(|h| h.y));
        Ok(ChartSpec {
            title: &self.title,
            x: &self.x,
            y: &self.y,
            x_range: axis_range(&self.x, xs, "x")?,
            y_range: axis_range(&self.y, ys, "y")?,
            width: self.width,
            height: self.height,
            legend: self
                .series
                .iter()
                .map(|s| LegendEntry {
                    label: s.label.clone(),
                    colour: s.colour,
                    swatch: Swatch::Line(s.style, s.width),
                })
                .collect(),
        })
    }

    /// The frame the plot uses (where data lands in the image).
    pub fn frame(&self) -> Result<Frame, RenderError> {
        Ok(self.render_with_frame()?.1)
    }

    /// Draws the plot.
    pub fn render(&self) -> Result<Image, RenderError> {
        Ok(self.render_with_frame()?.0)
    }

    /// Draws the plot and says where its data is.
    pub fn render_with_frame(&self) -> Result<(Image, Frame), RenderError> {
        let spec = self.spec()?;
        draw_rgb(self.width, self.height, [255; 3], |root| {
            let f = chart(root, &spec)?;
            check_area(&f, self.width, self.height)?;
            for h in &self.hlines {
                let py = f.to_px([f.x_range.0, h.y])[1];
                if !(py.is_finite() && f.contains([f.area[0] as f64, py])) {
                    continue;
                }
                let py = py.round() as i32;
                root.draw(&DashedPathElement::new(
                    vec![(f.area[0] as i32, py), (f.area[2] as i32, py)],
                    8,
                    5,
                    rgb(h.colour).stroke_width(2),
                ))
                .map_err(chart_err)?;
                if !h.label.is_empty() {
                    let st = (FONT, 12.0)
                        .into_font()
                        .color(&rgb(h.colour))
                        .pos(Pos::new(HPos::Right, VPos::Bottom));
                    root.draw(&Text::new(
                        h.label.as_str(),
                        (f.area[2] as i32 - 6, py - 4),
                        st,
                    ))
                    .map_err(chart_err)?;
                }
            }
            for s in &self.series {
                draw_polyline(root, &f, &s.points, s.colour, s.width, s.style)?;
            }
            Ok(f)
        })
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
/// `components`, Fx, Fy, Fz (thin: solid, dashed, dotted); an optional
/// safety threshold (N) as a dashed red line.
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
        plot.threshold(t, format!("limit {} N", linear_label(t)), [200, 30, 30]);
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
    /// The outline of the marker of radius `r` px, relative to its centre.
    pub(crate) fn outline(self, r: f64) -> Vec<(i32, i32)> {
        let pts: Vec<[f64; 2]> = match self {
            Marker::Circle => (0..16)
                .map(|k| {
                    let a = k as f64 / 16.0 * std::f64::consts::TAU;
                    [r * a.cos(), r * a.sin()]
                })
                .collect(),
            Marker::Square => {
                let h = r * 0.85;
                vec![[-h, -h], [h, -h], [h, h], [-h, h]]
            }
            Marker::Diamond => {
                let h = r * 1.2;
                vec![[0.0, -h], [h, 0.0], [0.0, h], [-h, 0.0]]
            }
            Marker::Triangle => {
                let h = r * 1.25;
                vec![[0.0, -h], [h * 0.95, h * 0.65], [-h * 0.95, h * 0.65]]
            }
        };
        pts.iter()
            .map(|p| (p[0].round() as i32, p[1].round() as i32))
            .collect()
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

    fn spec(&self) -> Result<ChartSpec<'_>, RenderError> {
        let xs = self
            .groups
            .iter()
            .flat_map(|g| g.points.iter().map(|p| p[0]));
        let ys = self
            .groups
            .iter()
            .flat_map(|g| g.points.iter().map(|p| p[1]));
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
                colour: FRONT_INK,
                swatch: Swatch::Line(LineStyle::Dashed, 1.5),
            });
        }
        Ok(ChartSpec {
            title: &self.title,
            x: &self.x,
            y: &self.y,
            x_range: axis_range(&self.x, xs, "x")?,
            y_range: axis_range(&self.y, ys, "y")?,
            width: self.width,
            height: self.height,
            legend,
        })
    }

    /// The frame the plot uses.
    pub fn frame(&self) -> Result<Frame, RenderError> {
        Ok(self.render_with_frame()?.1)
    }

    /// Draws the plot.
    pub fn render(&self) -> Result<Image, RenderError> {
        Ok(self.render_with_frame()?.0)
    }

    /// Draws the plot and says where its data is.
    pub fn render_with_frame(&self) -> Result<(Image, Frame), RenderError> {
        let spec = self.spec()?;
        draw_rgb(self.width, self.height, [255; 3], |root| {
            let f = chart(root, &spec)?;
            check_area(&f, self.width, self.height)?;
            let px = |p: [f64; 2]| {
                let q = f.to_px(p);
                (q[0].round() as i32, q[1].round() as i32)
            };
            // Only points inside the area take part in the front.
            let all: Vec<(usize, usize, [f64; 2])> = self
                .groups
                .iter()
                .enumerate()
                .flat_map(|(gi, g)| g.points.iter().enumerate().map(move |(pi, &p)| (gi, pi, p)))
                .filter(|(_, _, p)| {
                    let q = f.to_px(*p);
                    q.iter().all(|v| v.is_finite()) && f.contains(q)
                })
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
                        stair.push(px([p[0], all[front[k - 1]].2[1]]));
                    }
                    stair.push(px(p));
                }
                draw_stroke(root, stair, rgb(FRONT_INK), 1.5, LineStyle::Dashed)?;
            }
            for &(gi, _, p) in &all {
                let g = &self.groups[gi];
                draw_marker(root, px(p), g.marker, 4.5, rgb(g.colour))?;
            }
            let label_font = (FONT, 12.0).into_font().color(&rgb(FRONT_INK));
            for &i in &front {
                let (gi, pi, p) = all[i];
                let c = px(p);
                root.draw(&Circle::new(c, 8, rgb(FRONT_INK).stroke_width(1)))
                    .map_err(chart_err)?;
                if let Some(label) = self.groups[gi]
                    .point_labels
                    .get(pi)
                    .filter(|l| !l.is_empty())
                {
                    let st = label_font.clone().pos(Pos::new(HPos::Left, VPos::Bottom));
                    root.draw(&Text::new(label.as_str(), (c.0 + 9, c.1 - 6), st))
                        .map_err(chart_err)?;
                }
            }
            Ok(f)
        })
    }

    /// Draws the plot and writes it as a PNG.
    pub fn save_png(&self, path: impl AsRef<std::path::Path>) -> Result<(), RenderError> {
        self.render()?.save_png(path)
    }
}

#[cfg(test)]
mod tests {
    use super::chart::log_label;
    use super::*;

    fn is_colour(img: &Image, x: f64, y: f64, c: Rgb, tol: i32) -> bool {
        img.get(x as u32, y as u32).is_some_and(|p| {
            p.iter()
                .zip(c)
                .all(|(a, b)| (*a as i32 - b as i32).abs() <= tol)
        })
    }

    /// Whether colour `c` is within `r` px of (`x`, `y`).
    fn near_colour(img: &Image, x: f64, y: f64, c: Rgb, tol: i32, r: i64) -> bool {
        (-r..=r).any(|dy| (-r..=r).any(|dx| is_colour(img, x + dx as f64, y + dy as f64, c, tol)))
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
        let (img, frame) = plot.render_with_frame().unwrap();
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
        let (img, frame) = plot.render_with_frame().unwrap();
        let y = frame.to_px([0.0, 0.5])[1].round();
        let [l, _, r, _] = frame.area;
        let on = (l..r)
            .filter(|&x| {
                (-1..=1).any(|d| is_colour(&img, x as f64, y + d as f64, [200, 30, 30], 40))
            })
            .count();
        let span = (r - l) as usize;
        assert!(
            on > span / 3 && on < span * 9 / 10,
            "dashed coverage {on} of {span}"
        );
    }

    #[test]
    fn dashed_and_dotted_series_leave_gaps_and_solid_does_not() {
        let coverage = |style: LineStyle| {
            let c = [0, 0, 255];
            let mut plot = LinePlot::new(
                "",
                Axis::linear("x").with_range(0.0, 1.0),
                Axis::linear("y").with_range(0.0, 1.0),
            );
            plot.add(Series::new("", vec![[0.0, 0.5], [1.0, 0.5]], c).style(style));
            let (img, f) = plot.render_with_frame().unwrap();
            let y = f.to_px([0.0, 0.5])[1].round();
            let (l, r) = (f.area[0] + 5, f.area[2] - 5);
            let on = (l..r)
                .filter(|&x| (-1..=1).any(|d| is_colour(&img, x as f64, y + d as f64, c, 60)))
                .count();
            on as f64 / (r - l) as f64
        };
        assert!(coverage(LineStyle::Solid) > 0.98);
        let dashed = coverage(LineStyle::Dashed);
        assert!(dashed > 0.4 && dashed < 0.8, "dashed {dashed}");
        let dotted = coverage(LineStyle::Dotted);
        assert!(dotted > 0.2 && dotted < 0.8, "dotted {dotted}");
    }

    #[test]
    fn legend_shows_each_labelled_series_in_its_colour_right_of_the_area() {
        let (a, b) = ([200, 20, 20], [20, 150, 20]);
        let mut plot = LinePlot::new(
            "",
            Axis::linear("x").with_range(0.0, 1.0),
            Axis::linear("y").with_range(0.0, 1.0),
        );
        plot.add(Series::new("first", vec![[0.0, 0.2], [0.1, 0.2]], a));
        plot.add(Series::new("second", vec![[0.0, 0.3], [0.1, 0.3]], b));
        plot.add(Series::new("", vec![[0.0, 0.4], [0.1, 0.4]], [0, 0, 255]));
        let (img, f) = plot.render_with_frame().unwrap();
        let right_of = |c: Rgb| {
            (f.area[2] as u32 + 2..img.width())
                .flat_map(|x| (0..img.height()).map(move |y| (x, y)))
                .filter(|&(x, y)| is_colour(&img, x as f64, y as f64, c, 30))
                .count()
        };
        assert!(right_of(a) > 10 && right_of(b) > 10);
        // The unlabelled series has no legend entry.
        assert_eq!(right_of([0, 0, 255]), 0);
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
        let (img, frame) = plot.render_with_frame().unwrap();
        let y = frame.to_px([0.0, 0.5])[1];
        assert!(is_colour(&img, (frame.area[0] + 5) as f64, y, blue, 10));
        assert!(!near_colour(
            &img,
            (frame.area[0] - 20) as f64,
            y,
            blue,
            60,
            3
        ));
        assert!(!near_colour(
            &img,
            (frame.area[2] + 20) as f64,
            y,
            blue,
            60,
            3
        ));
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
        let (img, f) = plot.render_with_frame().unwrap();
        assert_eq!(f.x_range, (1e-3, 1e-1));
        let a = f.to_px([1e-3, 1e-2]);
        let b = f.to_px([1e-2, 1e-2]);
        let c = f.to_px([1e-1, 1e-2]);
        assert!(((b[0] - a[0]) - (c[0] - b[0])).abs() < 1e-9);
        assert!(f.to_px([-1.0, 1.0])[0].is_nan());
        let p = f.to_px([1e-3, 1e-1]);
        assert!(is_colour(&img, p[0], p[1], [0, 0, 200], 30));
    }

    #[test]
    fn tick_labels_read_as_numbers() {
        assert_eq!(linear_label(0.30000000000000004), "0.3");
        assert_eq!(linear_label(-2.0), "\u{2212}2");
        assert_eq!(linear_label(2e-5), "2e\u{2212}5");
        assert_eq!(log_label(1e-2), "0.01");
        assert_eq!(log_label(1e-5), "10⁻⁵");
        assert_eq!(log_label(3e-5), "");
    }

    #[test]
    fn nice_range_widens_outward_to_ticks() {
        assert_eq!(nice_range(0.0, 2.999, 6), (0.0, 3.0));
        let (lo, hi) = nice_range(0.13, 0.87, 5);
        assert!(
            (0.0..=0.13).contains(&lo) && (0.87..=1.0).contains(&hi),
            "{lo} {hi}"
        );
        let (lo, hi) = nice_range(2.0, 2.0, 5);
        assert!(lo < 2.0 && hi > 2.0);
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
        assert!(plot.render().is_err());
    }
}
