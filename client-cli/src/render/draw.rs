//! 2-D antialiased drawing primitives on an [`Image`]: rectangles, thick
//! (optionally dashed) polylines, discs and small filled polygons.
//!
//! Coordinates are in pixels with pixel (i, j) covering [i, i+1) x [j, j+1), so
//! its centre is (i + 0.5, j + 0.5). Lines are drawn from a coverage mask: a
//! pixel's coverage is `clamp(w/2 + 0.5 - d, 0, 1)` where `d` is the distance
//! from its centre to the polyline, and the mask keeps the maximum over the
//! segments so that joints of dense polylines are not painted twice.

use super::{Image, Rgb};

/// Fills the axis-aligned rectangle [x0, x1) x [y0, y1) (pixels, clipped).
pub fn fill_rect(img: &mut Image, x0: i64, y0: i64, x1: i64, y1: i64, colour: Rgb) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    for y in y0.max(0)..y1.min(h) {
        for x in x0.max(0)..x1.min(w) {
            img.put(x, y, colour);
        }
    }
}

/// Outlines the rectangle [x0, x1) x [y0, y1) with a 1-px line inside it.
pub fn stroke_rect(img: &mut Image, x0: i64, y0: i64, x1: i64, y1: i64, colour: Rgb) {
    fill_rect(img, x0, y0, x1, y0 + 1, colour);
    fill_rect(img, x0, y1 - 1, x1, y1, colour);
    fill_rect(img, x0, y0, x0 + 1, y1, colour);
    fill_rect(img, x1 - 1, y0, x1, y1, colour);
}

/// A dash pattern: `on` px drawn, `off` px skipped, along the arc length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dash {
    /// Drawn length, px.
    pub on: f64,
    /// Gap length, px.
    pub off: f64,
}

/// Distance from `p` to the segment `a`-`b`.
fn dist_to_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (qx, qy) = (a[0] + t * dx - p[0], a[1] + t * dy - p[1]);
    (qx * qx + qy * qy).sqrt()
}

/// Coverage mask of the image's size with the bounding box of what was drawn.
struct Mask {
    w: i64,
    h: i64,
    cov: Vec<f32>,
    lo: [i64; 2],
    hi: [i64; 2],
}

impl Mask {
    fn new(img: &Image) -> Self {
        let (w, h) = (img.width() as i64, img.height() as i64);
        Self {
            w,
            h,
            cov: vec![0.0; (w * h) as usize],
            lo: [w, h],
            hi: [-1, -1],
        }
    }

    fn segment(&mut self, a: [f64; 2], b: [f64; 2], half_width: f64) {
        let r = half_width + 1.0;
        let x0 = ((a[0].min(b[0]) - r).floor() as i64).max(0);
        let x1 = ((a[0].max(b[0]) + r).ceil() as i64).min(self.w - 1);
        let y0 = ((a[1].min(b[1]) - r).floor() as i64).max(0);
        let y1 = ((a[1].max(b[1]) + r).ceil() as i64).min(self.h - 1);
        if x0 > x1 || y0 > y1 {
            return;
        }
        self.lo = [self.lo[0].min(x0), self.lo[1].min(y0)];
        self.hi = [self.hi[0].max(x1), self.hi[1].max(y1)];
        for y in y0..=y1 {
            for x in x0..=x1 {
                let d = dist_to_segment([x as f64 + 0.5, y as f64 + 0.5], a, b);
                let c = (half_width + 0.5 - d).clamp(0.0, 1.0) as f32;
                let m = &mut self.cov[(y * self.w + x) as usize];
                *m = m.max(c);
            }
        }
    }

    fn apply(&self, img: &mut Image, colour: Rgb) {
        for y in self.lo[1]..=self.hi[1] {
            for x in self.lo[0]..=self.hi[0] {
                img.blend(x, y, colour, self.cov[(y * self.w + x) as usize]);
            }
        }
    }
}

/// Draws a polyline `width` px wide, solid or dashed. Non-finite points break
/// the line (a gap), so missing samples can be passed as NaN.
pub fn polyline(img: &mut Image, points: &[[f64; 2]], width: f64, colour: Rgb, dash: Option<Dash>) {
    let mut mask = Mask::new(img);
    let hw = 0.5 * width.max(0.0);
    let finite =
        |p: &[f64; 2]| p[0].is_finite() && p[1].is_finite() && p[0].abs() < 1e7 && p[1].abs() < 1e7;
    // Position in the dash pattern, px.
    let mut phase = 0.0;
    for pair in points.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if !finite(&a) || !finite(&b) {
            continue;
        }
        match dash {
            None => mask.segment(a, b, hw),
            Some(Dash { on, off }) if on > 0.0 && off >= 0.0 => {
                let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
                let period = on + off;
                let mut s = 0.0;
                while s < len {
                    let in_period = phase % period;
                    let (drawing, left) = if in_period < on {
                        (true, on - in_period)
                    } else {
                        (false, period - in_period)
                    };
                    let step = left.min(len - s);
                    if drawing {
                        let t0 = s / len;
                        let t1 = (s + step) / len;
                        let p = |t: f64| [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
                        mask.segment(p(t0), p(t1), hw);
                    }
                    s += step;
                    phase += step;
                }
            }
            Some(_) => mask.segment(a, b, hw),
        }
    }
    mask.apply(img, colour);
}

/// Draws a line segment `width` px wide.
pub fn line(img: &mut Image, a: [f64; 2], b: [f64; 2], width: f64, colour: Rgb) {
    polyline(img, &[a, b], width, colour, None);
}

/// Fills a disc of radius `r` px centred at `c`, antialiased.
pub fn disc(img: &mut Image, c: [f64; 2], r: f64, colour: Rgb) {
    let x0 = (c[0] - r - 1.0).floor() as i64;
    let x1 = (c[0] + r + 1.0).ceil() as i64;
    let y0 = (c[1] - r - 1.0).floor() as i64;
    let y1 = (c[1] + r + 1.0).ceil() as i64;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = ((x as f64 + 0.5 - c[0]).powi(2) + (y as f64 + 0.5 - c[1]).powi(2)).sqrt();
            img.blend(x, y, colour, (r + 0.5 - d).clamp(0.0, 1.0) as f32);
        }
    }
}

/// Fills a simple polygon (even-odd rule), antialiased with 4 x 4 samples a
/// pixel. Meant for small shapes: markers, arrow heads, legend swatches.
pub fn fill_polygon(img: &mut Image, pts: &[[f64; 2]], colour: Rgb) {
    if pts.len() < 3 || pts.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
        return;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in pts {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let inside = |x: f64, y: f64| {
        let mut odd = false;
        let mut j = pts.len() - 1;
        for i in 0..pts.len() {
            let (a, b) = (pts[i], pts[j]);
            if (a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0] {
                odd = !odd;
            }
            j = i;
        }
        odd
    };
    let x0 = (lo[0].floor() as i64).max(0);
    let x1 = (hi[0].ceil() as i64).min(img.width() as i64 - 1);
    let y0 = (lo[1].floor() as i64).max(0);
    let y1 = (hi[1].ceil() as i64).min(img.height() as i64 - 1);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let mut n = 0;
            for sy in 0..4 {
                for sx in 0..4 {
                    if inside(
                        x as f64 + (sx as f64 + 0.5) / 4.0,
                        y as f64 + (sy as f64 + 0.5) / 4.0,
                    ) {
                        n += 1;
                    }
                }
            }
            img.blend(x, y, colour, n as f32 / 16.0);
        }
    }
}

/// Linear interpolation between two colours, `t` in [0, 1].
pub fn mix(a: Rgb, b: Rgb, t: f64) -> Rgb {
    let t = t.clamp(0.0, 1.0);
    [0, 1, 2].map(|i| (a[i] as f64 + (b[i] as f64 - a[i] as f64) * t).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn horizontal_line_covers_its_row_only() {
        let mut img = Image::new(20, 10, [255; 3]).unwrap();
        line(&mut img, [2.0, 5.5], [18.0, 5.5], 1.0, [0; 3]);
        assert_eq!(img.get(10, 5), Some([0; 3]));
        assert_eq!(img.get(10, 3), Some([255; 3]));
        assert_eq!(img.get(10, 7), Some([255; 3]));
        assert_eq!(img.get(0, 5), Some([255; 3]));
    }

    #[test]
    fn dashes_leave_gaps() {
        let mut img = Image::new(40, 5, [255; 3]).unwrap();
        polyline(
            &mut img,
            &[[0.0, 2.5], [40.0, 2.5]],
            1.0,
            [0; 3],
            Some(Dash { on: 5.0, off: 5.0 }),
        );
        assert_eq!(img.get(2, 2), Some([0; 3]));
        assert_eq!(img.get(7, 2), Some([255; 3]));
        assert_eq!(img.get(12, 2), Some([0; 3]));
    }

    #[test]
    fn polygon_fills_inside_not_outside() {
        let mut img = Image::new(10, 10, [255; 3]).unwrap();
        fill_polygon(
            &mut img,
            &[[2.0, 2.0], [8.0, 2.0], [8.0, 8.0], [2.0, 8.0]],
            [0; 3],
        );
        assert_eq!(img.get(5, 5), Some([0; 3]));
        assert_eq!(img.get(9, 9), Some([255; 3]));
        assert_eq!(img.get(1, 5), Some([255; 3]));
    }
}
