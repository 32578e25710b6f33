//! Validation of incoming poses: the conversion from wire values to an engine
//! pose, with the checks the contract promises (finite values, unit quaternion,
//! sequence and time going forward).

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// Largest deviation of a quaternion's norm from 1 that is accepted.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 1e-3;

/// A pose as received: timestamp, sequence, position (m), quaternion (w, x, y, z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawPose {
    /// Client timestamp, s.
    pub t_s: f64,
    /// Client sequence number.
    pub sequence: u64,
    /// Position of the handle point, m.
    pub position_m: [f64; 3],
    /// Orientation quaternion (w, x, y, z).
    pub orientation: [f64; 4],
}

/// An accepted pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedPose {
    /// Client timestamp, s.
    pub t_s: f64,
    /// Client sequence number.
    pub sequence: u64,
    /// Instrument frame to scene frame.
    pub pose: Isometry3<f64>,
}

/// Why a pose was rejected; the message names the field.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum PoseError {
    /// A missing field.
    #[error("pose field `{0}` is missing")]
    Missing(&'static str),
    /// A NaN or infinite value.
    #[error("pose field `{field}` is not finite ({value})")]
    NonFinite { field: &'static str, value: f64 },
    /// The quaternion is not unit length (`norm` computed without underflow,
    /// so a subnormal quaternion reports its tiny norm, not 0).
    #[error("pose field `orientation` is not a unit quaternion (norm {})", show_norm(*norm))]
    NotUnit { norm: f64 },
    /// Sequence number not increasing.
    #[error("pose sequence {got} does not follow {last}")]
    SequenceBack { got: u64, last: u64 },
    /// Timestamp going back.
    #[error("pose timestamp t_s = {got} s is before the previous {last} s")]
    TimeBack { got: f64, last: f64 },
    /// Stepped mode: the pose is older than the session's clock (the time
    /// the other instruments' poses have reached): it would change the
    /// past.
    #[error(
        "pose timestamp t_s = {got} s is behind the stepped clock ({clock} s): the session has already been answered up to there"
    )]
    BehindClock { got: f64, clock: f64 },
    /// The pose could not be answered.
    #[error("the pose was not answered: {0}")]
    NotAnswered(String),
}

/// A norm as a person reads it: plain between 1e-3 and 1e6, in exponent
/// form beyond (a subnormal norm prints as `5e-324`, not as 0.000...).
fn show_norm(norm: f64) -> String {
    if norm == 0.0 || (1e-3..1e6).contains(&norm) {
        format!("{norm}")
    } else {
        format!("{norm:e}")
    }
}

/// The Euclidean norm of `v`, scaled by its largest component so that
/// neither subnormal nor huge components underflow or overflow the squares.
fn scaled_norm(v: &[f64; 4]) -> f64 {
    let scale = v.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    if scale == 0.0 {
        return 0.0;
    }
    scale * v.iter().map(|c| (c / scale).powi(2)).sum::<f64>().sqrt()
}

/// Checks one pose against the previous accepted one (if any) and converts it.
pub fn validate(raw: &RawPose, last: Option<&TimedPose>) -> Result<TimedPose, PoseError> {
    let named = [
        ("t_s", raw.t_s),
        ("position_m.x", raw.position_m[0]),
        ("position_m.y", raw.position_m[1]),
        ("position_m.z", raw.position_m[2]),
        ("orientation.w", raw.orientation[0]),
        ("orientation.x", raw.orientation[1]),
        ("orientation.y", raw.orientation[2]),
        ("orientation.z", raw.orientation[3]),
    ];
    for (field, value) in named {
        if !value.is_finite() {
            return Err(PoseError::NonFinite { field, value });
        }
    }
    let [w, x, y, z] = raw.orientation;
    let q = Quaternion::new(w, x, y, z);
    let norm = scaled_norm(&raw.orientation);
    if (norm - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
        return Err(PoseError::NotUnit { norm });
    }
    if let Some(last) = last {
        if raw.sequence <= last.sequence {
            return Err(PoseError::SequenceBack {
                got: raw.sequence,
                last: last.sequence,
            });
        }
        if raw.t_s < last.t_s {
            return Err(PoseError::TimeBack {
                got: raw.t_s,
                last: last.t_s,
            });
        }
    }
    let [px, py, pz] = raw.position_m;
    Ok(TimedPose {
        t_s: raw.t_s,
        sequence: raw.sequence,
        pose: Isometry3::from_parts(
            Translation3::new(px, py, pz),
            UnitQuaternion::new_normalize(q),
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(t: f64, seq: u64) -> RawPose {
        RawPose {
            t_s: t,
            sequence: seq,
            position_m: [0.0, 0.0, 0.1],
            orientation: [1.0, 0.0, 0.0, 0.0],
        }
    }

    #[test]
    fn accepts_and_rejects() {
        let a = validate(&raw(0.0, 1), None).unwrap();
        assert_eq!(a.pose.translation.z, 0.1);
        let mut r = raw(0.001, 2);
        r.position_m[1] = f64::NAN;
        assert_eq!(
            validate(&r, Some(&a)).unwrap_err().to_string(),
            "pose field `position_m.y` is not finite (NaN)"
        );
        let mut r = raw(0.001, 2);
        r.orientation = [0.0; 4];
        assert!(matches!(
            validate(&r, Some(&a)),
            Err(PoseError::NotUnit { .. })
        ));
        r.orientation = [1.0005, 0.0, 0.0, 0.0];
        assert!(
            validate(&r, Some(&a)).is_ok(),
            "within tolerance is accepted and normalised"
        );
        assert!(matches!(
            validate(&raw(0.001, 1), Some(&a)),
            Err(PoseError::SequenceBack { .. })
        ));
        assert!(matches!(
            validate(&raw(-0.001, 3), Some(&a)),
            Err(PoseError::TimeBack { .. })
        ));
        let r = RawPose {
            t_s: f64::INFINITY,
            ..raw(0.0, 9)
        };
        assert!(matches!(
            validate(&r, Some(&a)),
            Err(PoseError::NonFinite { field: "t_s", .. })
        ));
    }
}

#[cfg(test)]
mod norm_tests {
    use super::*;

    /// A quaternion whose components are subnormal is reported with its own
    /// tiny norm (the smallest subnormal, 4.9e-324), not with "norm 0"; the
    /// zero quaternion with norm 0; huge components do not overflow to inf.
    #[test]
    fn the_reported_norm_does_not_underflow() {
        let pose = |q: [f64; 4]| RawPose {
            t_s: 0.0,
            sequence: 1,
            position_m: [0.0; 3],
            orientation: q,
        };
        let tiny = f64::from_bits(1);
        match validate(&pose([tiny, 0.0, 0.0, 0.0]), None) {
            Err(PoseError::NotUnit { norm }) => assert_eq!(norm, tiny),
            other => panic!("{other:?}"),
        }
        let e = validate(&pose([tiny, 0.0, 0.0, 0.0]), None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "pose field `orientation` is not a unit quaternion (norm 5e-324)"
        );
        match validate(&pose([3e-310, 4e-310, 0.0, 0.0]), None) {
            Err(PoseError::NotUnit { norm }) => assert!((norm / 5e-310 - 1.0).abs() < 1e-12),
            other => panic!("{other:?}"),
        }
        match validate(&pose([0.0; 4]), None) {
            Err(PoseError::NotUnit { norm }) => assert_eq!(norm, 0.0),
            other => panic!("{other:?}"),
        }
        match validate(&pose([1e300, 1e300, 0.0, 0.0]), None) {
            Err(PoseError::NotUnit { norm }) => {
                assert!((norm / (1e300 * 2f64.sqrt()) - 1.0).abs() < 1e-12)
            }
            other => panic!("{other:?}"),
        }
        // A unit quaternion given as 0.6, 0.8 is accepted.
        assert!(validate(&pose([0.6, 0.8, 0.0, 0.0]), None).is_ok());
    }
}
