//! Perceptual colour maps.
//!
//! A scalar `v` is shown with `t = (v - lo) / (hi - lo)` clamped to [0, 1];
//! the maps come from the `colorous` crate (matplotlib's viridis, inferno and
//! cividis; d3's red-blue, reversed so that negative is blue). Non-finite
//! values are drawn in [`NAN_COLOUR`].

use super::Rgb;

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
    }
}
