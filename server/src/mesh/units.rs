//! Units of model files: a check that positions are plausible in metres, and
//! the scale that converts them.
//!
//! Mesh files carry no unit, and most tools of the field write millimetres
//! (FreeSurfer surfaces, CAD exports, many Gmsh models). Read as metres, a
//! brain in millimetres is 150 m across: the mesher then asks for an
//! impossible lattice and a scene would simulate a building-sized brain with
//! tissue parameters meant for 0.15 m. A model wider than
//! [`MAX_MODEL_EXTENT_M`] is refused with the likely unit and the scale that
//! converts it ([`suggest`]).

use nalgebra::Point3;

/// Largest extent (the longest side of the bounding box) accepted for a
/// model in metres, m. A human brain is about 0.17 m long.
pub const MAX_MODEL_EXTENT_M: f64 = 1.0;

/// A model too large to be in metres.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error, serde::Serialize)]
#[error(
    "the model is {extent_m:.4} m across (the longest side of its bounding box), \
     implausible for a brain model in metres (at most {MAX_MODEL_EXTENT_M} m): \
     this looks like {unit}"
)]
pub struct ImplausibleSize {
    /// The longest side of the bounding box, in the file's unit read as m.
    pub extent_m: f64,
    /// The unit the positions are probably in, e.g. "millimetres".
    pub unit: &'static str,
    /// The factor that converts them to metres, e.g. 0.001.
    pub scale: f64,
}

/// The likely unit of a model whose extent, read as metres, is `extent`
/// (above [`MAX_MODEL_EXTENT_M`]): micrometres beyond 1000 (a brain in mm is
/// at most a few hundred), millimetres from 5 (the unit of most of the
/// field's tools; a brain in centimetres, 15 to 20 across, is taken for
/// millimetres too, and the message gives the extent to check), and
/// centimetres from 1 to 5.
pub fn suggest(extent: f64) -> (&'static str, f64) {
    if extent > 1000.0 {
        ("micrometres", 1e-6)
    } else if extent >= 5.0 {
        ("millimetres", 1e-3)
    } else {
        ("centimetres", 1e-2)
    }
}

/// The longest side of the bounding box of `points`, m (0 without points;
/// non-finite coordinates are skipped).
pub fn extent(points: &[Point3<f64>]) -> f64 {
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    for p in points.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let d = hi - lo;
    if d.iter().all(|c| c.is_finite()) {
        d.max()
    } else {
        0.0
    }
}

/// Checks that `points` (read as m) span at most `max_extent_m`.
pub fn check_extent(points: &[Point3<f64>], max_extent_m: f64) -> Result<(), ImplausibleSize> {
    let extent_m = extent(points);
    if extent_m > max_extent_m {
        let (unit, scale) = suggest(extent_m);
        return Err(ImplausibleSize {
            extent_m,
            unit,
            scale,
        });
    }
    Ok(())
}

/// Multiplies every position by `scale` (positions in a file's unit to m).
pub fn scale_points(points: &mut [Point3<f64>], scale: f64) {
    if scale != 1.0 {
        for p in points {
            p.coords *= scale;
        }
    }
}

/// Checks that a scale factor is a finite positive number; `what` names it
/// in the error (`--scale`, `model.scale`).
pub fn check_scale(scale: f64, what: &str) -> Result<(), String> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(format!(
            "{what} must be a finite positive factor from the file's unit to metres \
             (0.001 for millimetres), got {scale}"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fsaverage pial surface in mm (137.6 mm long) is refused as
    /// millimetres; the same in m passes; a brain in cm (15) is centimetres;
    /// one in micrometres is named so; exactly 1 m passes.
    #[test]
    fn sizes_beyond_a_metre_name_the_unit_and_the_scale() {
        let box_of = |side: f64| vec![Point3::origin(), Point3::new(side, side * 0.5, 0.1)];
        let e = check_extent(&box_of(137.6), MAX_MODEL_EXTENT_M).unwrap_err();
        assert_eq!((e.unit, e.scale), ("millimetres", 1e-3));
        assert!(
            e.to_string()
                .ends_with("at most 1 m): this looks like millimetres"),
            "{e}"
        );
        assert!(check_extent(&box_of(0.1376), MAX_MODEL_EXTENT_M).is_ok());
        assert!(check_extent(&box_of(1.0), MAX_MODEL_EXTENT_M).is_ok());
        assert_eq!(
            check_extent(&box_of(15.0), MAX_MODEL_EXTENT_M)
                .unwrap_err()
                .unit,
            "millimetres"
        );
        assert_eq!(suggest(3.0), ("centimetres", 1e-2));
        assert_eq!(suggest(150_000.0), ("micrometres", 1e-6));
        // NaN coordinates are not a size.
        assert_eq!(extent(&[Point3::new(f64::NAN, 0.0, 0.0)]), 0.0);
        let mut p = box_of(137.6);
        scale_points(&mut p, 1e-3);
        assert!((extent(&p) - 0.1376).abs() < 1e-15);
        assert!(check_scale(0.0, "--scale").is_err());
        assert!(check_scale(f64::NAN, "--scale").is_err());
        assert!(check_scale(1e-3, "--scale").is_ok());
    }
}
