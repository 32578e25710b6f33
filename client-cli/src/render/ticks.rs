//! Axis ticks: "nice" linear steps (1, 2 or 5 times a power of ten) and
//! decade ticks for logarithmic axes, with their labels.

/// A tick: its value (data units) and label (empty for minor ticks).
#[derive(Debug, Clone, PartialEq)]
pub struct Tick {
    /// Position, data units.
    pub value: f64,
    /// Label; empty for a minor tick.
    pub label: String,
}

/// The nice step (1, 2 or 5 x 10^k) that splits `span` into about `target`
/// intervals.
pub fn nice_step(span: f64, target: usize) -> f64 {
    let raw = span.abs() / target.max(1) as f64;
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let mag = 10f64.powf(raw.log10().floor());
    let m = raw / mag;
    let nice = if m < 1.5 {
        1.0
    } else if m < 3.0 {
        2.0
    } else if m < 7.0 {
        5.0
    } else {
        10.0
    };
    nice * mag
}

/// Formats `v` with as many decimals as `step` needs; uses a true minus sign
/// and scientific notation for very large or small magnitudes.
pub fn format_value(v: f64, step: f64) -> String {
    let v = if v.abs() < step.abs() * 1e-9 { 0.0 } else { v };
    let big = v.abs().max(step.abs());
    let s = if big >= 1e5 || (step.abs() < 1e-4 && v != 0.0) {
        let s = format!("{v:.1e}");
        s.replace(".0e", "e")
    } else {
        let decimals = (-step.abs().log10().floor()).max(0.0) as usize;
        // Steps like 0.25 need one more decimal than their magnitude says.
        let decimals = if (step / 10f64.powi(-(decimals as i32))).fract().abs() > 1e-6 {
            decimals + 1
        } else {
            decimals
        };
        format!("{v:.decimals$}")
    };
    s.replace('-', "\u{2212}")
}

/// Linear ticks covering [lo, hi] with about `target` intervals; returns the
/// ticks inside the range (labelled) and the step.
pub fn linear(lo: f64, hi: f64, target: usize) -> (Vec<Tick>, f64) {
    let step = nice_step(hi - lo, target);
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    let ticks = (first..=last)
        .map(|i| {
            let value = i as f64 * step;
            Tick {
                value,
                label: format_value(value, step),
            }
        })
        .collect();
    (ticks, step)
}

/// Range [lo, hi] widened outwards to whole nice steps, as axes use.
pub fn nice_range(lo: f64, hi: f64, target: usize) -> (f64, f64) {
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        let pad = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        (lo - pad, hi + pad)
    };
    let step = nice_step(hi - lo, target);
    (
        (lo / step + 1e-9).floor() * step,
        (hi / step - 1e-9).ceil() * step,
    )
}

fn superscript(n: i32) -> String {
    const DIGITS: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    let mut s = String::new();
    if n < 0 {
        s.push('⁻');
    }
    for c in n.unsigned_abs().to_string().chars() {
        s.push(DIGITS[c.to_digit(10).unwrap_or(0) as usize]);
    }
    s
}

/// Label of the decade 10^k: plain between 0.001 and 1000, else "10ᵏ".
pub fn decade_label(k: i32) -> String {
    if (-3..=3).contains(&k) {
        format_value(10f64.powi(k), 10f64.powi(k))
    } else {
        format!("10{}", superscript(k))
    }
}

/// Logarithmic ticks for [lo, hi] (both > 0): labelled decades and unlabelled
/// 2..9 minor ticks; when the range spans less than one decade, labelled
/// 1-2-5 ticks instead.
pub fn log10(lo: f64, hi: f64) -> Vec<Tick> {
    let (a, b) = (lo.log10(), hi.log10());
    let mut ticks = Vec::new();
    if !(a.is_finite() && b.is_finite()) {
        return ticks;
    }
    let (k0, k1) = (a.floor() as i32, b.ceil() as i32);
    let decades_inside = (k0..=k1)
        .filter(|&k| (k as f64) >= a - 1e-9 && (k as f64) <= b + 1e-9)
        .count();
    let labelled_minor = decades_inside < 2;
    // With many decades, label every second or third one.
    let every = ((k1 - k0) as usize / 8 + 1) as i32;
    for k in k0..=k1 {
        for m in 1..10 {
            let v = m as f64 * 10f64.powi(k);
            if v < lo * (1.0 - 1e-9) || v > hi * (1.0 + 1e-9) {
                continue;
            }
            let label = if m == 1 && k.rem_euclid(every) == 0 {
                decade_label(k)
            } else if labelled_minor && (m == 2 || m == 5) {
                format_value(v, 10f64.powi(k))
            } else {
                String::new()
            };
            ticks.push(Tick { value: v, label });
        }
    }
    ticks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps() {
        assert_eq!(nice_step(10.0, 5), 2.0);
        assert_eq!(nice_step(1.0, 4), 0.2);
        assert!((nice_step(0.003, 5) - 0.0005).abs() < 1e-15);
        assert_eq!(nice_step(0.0, 5), 1.0);
    }

    #[test]
    fn linear_ticks_cover_the_range_with_clean_labels() {
        let (t, step) = linear(0.0, 1.0, 5);
        assert_eq!(step, 0.2);
        let labels: Vec<&str> = t.iter().map(|t| t.label.as_str()).collect();
        assert_eq!(labels, ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        let (t, _) = linear(-3.0, 3.0, 6);
        assert_eq!(t[0].label, "\u{2212}3");
        assert_eq!(t.last().unwrap().label, "3");
    }

    #[test]
    fn nice_range_widens_outward() {
        assert_eq!(nice_range(0.13, 0.87, 5), (0.1, 0.9));
        assert_eq!(nice_range(0.13, 0.87, 2), (0.0, 1.0));
        assert_eq!(nice_range(0.0, 2.999, 6), (0.0, 3.0));
        assert_eq!(nice_range(-1.0, 3.0, 4), (-1.0, 3.0));
        let (lo, hi) = nice_range(2.0, 2.0, 5);
        assert!(lo < 2.0 && hi > 2.0);
    }

    #[test]
    fn log_ticks_label_decades() {
        let t = log10(1e-4, 1.0);
        let labelled: Vec<&str> = t
            .iter()
            .filter(|t| !t.label.is_empty())
            .map(|t| t.label.as_str())
            .collect();
        assert_eq!(labelled, ["10⁻⁴", "0.001", "0.01", "0.1", "1"]);
        assert_eq!(t.len(), 4 * 9 + 1);
        let t = log10(2.0, 8.0);
        assert!(t.iter().any(|t| t.label == "5"));
    }
}
