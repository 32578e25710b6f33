//! Perceptual colour maps and the legend bar that explains them.
//!
//! A scalar `v` is shown with `t = (v - lo) / (hi - lo)` clamped to [0, 1];
//! the maps come from the `colorous` crate (matplotlib's viridis, inferno and
//! cividis; d3's red-blue, reversed so that negative is blue). Non-finite
//! values are drawn in [`NAN_COLOUR`].

use super::draw::{fill_rect, line, stroke_rect};
use super::text::{HAlign, TextStyle, VAlign, draw_text, measure};
use super::{Image, Rgb, ticks};

/// Colour of a non-finite scalar.
pub const NAN_COLOUR: Rgb = [160, 160, 160];

/// A colour map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Colormap {
    /// Sequential, dark blue-violet to yellow (matplotlib's viridis).
    #[default]
    Viridis,
    /// Sequential, black through red to pale yellow (matplotlib's inferno).
    Inferno,
    /// Sequential and readable with colour-vision deficiency (cividis).
    Cividis,
    /// Diverging: blue (low) through near-white (middle) to red (high).
    BlueRed,
}

impl Colormap {
    /// The colour at `t` in [0, 1] (clamped; NaN gives [`NAN_COLOUR`]).
    pub fn sample(self, t: f64) -> Rgb {
        if t.is_nan() {
            return NAN_COLOUR;
        }
        let t = t.clamp(0.0, 1.0);
        let c = match self {
            Colormap::Viridis => colorous::VIRIDIS.eval_continuous(t),
            Colormap::Inferno => colorous::INFERNO.eval_continuous(t),
            Colormap::Cividis => colorous::CIVIDIS.eval_continuous(t),
            Colormap::BlueRed => colorous::RED_BLUE.eval_continuous(1.0 - t),
        };
        c.as_array()
    }

    /// The colour of value `v` on the range [`lo`, `hi`].
    pub fn map(self, v: f64, lo: f64, hi: f64) -> Rgb {
        self.sample(normalise(v, lo, hi))
    }
}

/// `(v - lo) / (hi - lo)`; 0.5 for an empty range; NaN for a non-finite `v`.
pub fn normalise(v: f64, lo: f64, hi: f64) -> f64 {
    if !v.is_finite() {
        return f64::NAN;
    }
    let span = hi - lo;
    if span.abs() <= f64::EPSILON * lo.abs().max(hi.abs()).max(f64::MIN_POSITIVE) {
        0.5
    } else {
        (v - lo) / span
    }
}

/// The finite minimum and maximum of `values`, or `None` when there is none.
pub fn finite_range(values: &[f64]) -> Option<(f64, f64)> {
    values
        .iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, &v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// The symmetric range [-m, m] with m the largest finite |value| (for
/// diverging maps, so that zero is the neutral middle).
pub fn symmetric_range(values: &[f64]) -> Option<(f64, f64)> {
    finite_range(values).map(|(lo, hi)| {
        let m = lo.abs().max(hi.abs());
        (-m, m)
    })
}

/// A vertical legend bar: the map from `range.0` (bottom) to `range.1` (top),
/// with tick labels on its right and a title above.
#[derive(Debug, Clone, PartialEq)]
pub struct Legend {
    /// The map shown.
    pub map: Colormap,
    /// Values at the bottom and the top of the bar, in display units.
    pub range: (f64, f64),
    /// Title (quantity and unit), drawn above the bar, e.g. "height (mm)".
    pub title: String,
    /// Text size, px.
    pub text_size: f32,
}

impl Legend {
    /// A legend of `map` over `range` titled `title`, with 14 px text.
    pub fn new(map: Colormap, range: (f64, f64), title: impl Into<String>) -> Self {
        Self {
            map,
            range,
            title: title.into(),
            text_size: 14.0,
        }
    }

    /// Draws the legend with the bar at [x, x + bar_w) x [y, y + bar_h) px;
    /// the title goes above `y` and the labels right of the bar.
    pub fn draw(&self, img: &mut Image, x: i64, y: i64, bar_w: i64, bar_h: i64) {
        let (lo, hi) = self.range;
        let ink = [40, 40, 40];
        for j in 0..bar_h {
            let t = 1.0 - (j as f64 + 0.5) / bar_h as f64;
            fill_rect(img, x, y + j, x + bar_w, y + j + 1, self.map.sample(t));
        }
        stroke_rect(img, x, y, x + bar_w, y + bar_h, [90, 90, 90]);
        let target = (bar_h / 45).clamp(2, 8) as usize;
        let (ticks, _) = if hi > lo {
            ticks::linear(lo, hi, target)
        } else {
            ticks::linear(hi, lo, target)
        };
        let style = TextStyle::new(self.text_size)
            .colour(ink)
            .align(HAlign::Left, VAlign::Middle);
        for t in ticks {
            let f = normalise(t.value, lo, hi);
            if !(0.0..=1.0).contains(&f) {
                continue;
            }
            let py = y as f64 + (1.0 - f) * (bar_h - 1) as f64 + 0.5;
            let right = (x + bar_w) as f64;
            line(img, [right - 4.0, py], [right + 3.0, py], 1.0, ink);
            draw_text(img, &t.label, (x + bar_w + 6) as f32, py as f32, &style);
        }
        if !self.title.is_empty() {
            let st = TextStyle::new(self.text_size)
                .colour(ink)
                .align(HAlign::Left, VAlign::Bottom);
            draw_text(img, &self.title, x as f32, (y - 6) as f32, &st);
        }
    }

    /// Width the legend needs right of `x` for bar width `bar_w`, px.
    pub fn width(&self, bar_w: i64) -> i64 {
        let style = TextStyle::new(self.text_size);
        let (lo, hi) = self.range;
        let (ticks, _) = ticks::linear(lo.min(hi), lo.max(hi), 6);
        let labels = ticks
            .iter()
            .map(|t| measure(&t.label, &style).width)
            .fold(0.0, f32::max);
        let title = measure(&self.title, &style).width;
        (bar_w as f32 + 6.0 + labels).max(title).ceil() as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_endpoints_are_matplotlibs() {
        // matplotlib: viridis(0) = #440154, viridis(1) = #fde725.
        let near = |a: Rgb, b: Rgb| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (*x as i32 - y as i32).abs() <= 2)
        };
        assert!(near(Colormap::Viridis.sample(0.0), [0x44, 0x01, 0x54]));
        assert!(near(Colormap::Viridis.sample(1.0), [0xfd, 0xe7, 0x25]));
        // Clamped outside [0, 1].
        assert_eq!(
            Colormap::Viridis.sample(-3.0),
            Colormap::Viridis.sample(0.0)
        );
        assert_eq!(Colormap::Viridis.sample(7.0), Colormap::Viridis.sample(1.0));
    }

    #[test]
    fn viridis_brightens_monotonically() {
        let lum = |c: Rgb| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        let mut prev = -1.0;
        for i in 0..=50 {
            let l = lum(Colormap::Viridis.sample(i as f64 / 50.0));
            assert!(l > prev, "luminance drops at {i}");
            prev = l;
        }
    }

    #[test]
    fn diverging_is_blue_low_red_high_light_middle() {
        let lo = Colormap::BlueRed.sample(0.0);
        let hi = Colormap::BlueRed.sample(1.0);
        let mid = Colormap::BlueRed.sample(0.5);
        assert!(lo[2] > lo[0], "low end {lo:?} is not blue");
        assert!(hi[0] > hi[2], "high end {hi:?} is not red");
        assert!(mid.iter().all(|&c| c > 220), "middle {mid:?} is not light");
    }

    #[test]
    fn nan_and_empty_ranges() {
        assert_eq!(Colormap::Viridis.map(f64::NAN, 0.0, 1.0), NAN_COLOUR);
        assert_eq!(normalise(3.0, 3.0, 3.0), 0.5);
        assert_eq!(
            finite_range(&[f64::NAN, 2.0, -1.0, f64::INFINITY]),
            Some((-1.0, 2.0))
        );
        assert_eq!(symmetric_range(&[-1.0, 3.0]), Some((-3.0, 3.0)));
        assert_eq!(finite_range(&[f64::NAN]), None);
    }

    #[test]
    fn legend_bar_runs_from_low_colour_at_bottom_to_high_at_top() {
        let mut img = Image::new(200, 300, [255; 3]).unwrap();
        let legend = Legend::new(Colormap::Viridis, (0.0, 10.0), "height (mm)");
        legend.draw(&mut img, 20, 40, 20, 200);
        let top = img.get(30, 42).unwrap();
        let bottom = img.get(30, 237).unwrap();
        let near = |a: Rgb, b: Rgb| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (*x as i32 - y as i32).abs() <= 8)
        };
        assert!(near(top, Colormap::Viridis.sample(1.0)), "top {top:?}");
        assert!(
            near(bottom, Colormap::Viridis.sample(0.0)),
            "bottom {bottom:?}"
        );
        // Labels right of the bar put ink there.
        let ink = (45..120)
            .flat_map(|x| (40..240).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get(x, y).unwrap()[0] < 128)
            .count();
        assert!(ink > 50);
    }
}
