//! The thresholds a session's injury measures are scored against (a scene's
//! `[assessment]`, `fissure.v1.AssessmentThresholds` in the recordings),
//! each as a warning level and a failing level. It lives here, beside the
//! messages that carry it, so that a client scoring a recording uses the
//! server's levels and defaults without linking the server.
//!
//! Defaults and where they come from (docs/DESIGN.md section 3e):
//!
//! * **Retraction pressure** (the mean normal pressure under an
//!   instrument): 20 mmHg (2.67 kPa) warns, 30 mmHg (4.00 kPa) fails. J.
//!   Rosenørn and N. H. Diemer, "The risk of cerebral damage during graded
//!   brain retractor pressure in the rat", J. Neurosurg. 63(4):608-611,
//!   1985: after 15 min of retractor pressure, 1 of 6 brains had a cortical
//!   infarct at 20 mmHg, 5 of 6 at 30 mmHg and 6 of 6 at 40 mmHg; their
//!   earlier study showed a considerable fall of regional blood flow at
//!   30 mmHg. A rat model and a sensor under the blade: the human threshold
//!   is uncertain, and a simulated mean pressure depends on the contact
//!   area the mesh resolves.
//! * **Time above the warning pressure**: 5 min warns, 15 min fails. The
//!   15 min is Rosenørn and Diemer's exposure; the 5 min warning is an
//!   assumption (intermittent retraction, releasing every few minutes, is
//!   the usual advice).
//! * **Pressure-time product** (the mean pressure integrated over the
//!   session): 100 mmHg min (0.8 MPa s) warns, 300 mmHg min (2.4 MPa s)
//!   fails. 300 mmHg min is 20 mmHg held for 15 min, the exposure that
//!   spared 5 of 6 rat brains; the warning at a third of it is an
//!   assumption.
//! * **Tissue strain** (the largest principal Green-Lagrange strain of a
//!   tetrahedron): 0.14 warns, 0.21 fails. A. C. Bain and D. F. Meaney,
//!   "Tissue-level thresholds for axonal damage in an experimental model
//!   of central nervous system white matter injury", J. Biomech. Eng.
//!   122(6):615-622, 2000: for morphological axonal damage of the guinea
//!   pig optic nerve, the conservative threshold is a Lagrangian strain of
//!   0.14 and the optimal one 0.21. Their stretch was dynamic; at the slow
//!   rates of retraction the threshold is uncertain (probably higher).
//! * **Strained volume** (the tissue above the warning strain): 1 mm^3
//!   warns, 100 mm^3 fails. Assumed: no published figure ties a volume of
//!   overstretched tissue to an outcome.

use serde::{Deserialize, Serialize};

/// One mmHg, Pa.
pub const PA_PER_MMHG: f64 = 133.322_387_415;

/// A warning level and a failing level of one measure (same units as the
/// measure; `warn <= fail`).
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Levels {
    /// At or above it, the measure warns.
    pub warn: f64,
    /// At or above it, the measure fails.
    pub fail: f64,
}

impl Levels {
    /// Where `value` stands.
    pub fn grade(&self, value: f64) -> Grade {
        if value >= self.fail {
            Grade::Fail
        } else if value >= self.warn {
            Grade::Warn
        } else {
            Grade::Pass
        }
    }
}

/// A measure against its levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Grade {
    /// Below the warning level.
    Pass,
    /// At or above the warning level, below the failing one.
    Warn,
    /// At or above the failing level.
    Fail,
}

impl Grade {
    /// `pass`, `warn` or `fail`.
    pub fn name(self) -> &'static str {
        match self {
            Grade::Pass => "pass",
            Grade::Warn => "warn",
            Grade::Fail => "fail",
        }
    }
}

/// `[assessment]`: the thresholds of the injury measures.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct AssessmentSpec {
    /// Mean retraction pressure under an instrument, Pa.
    pub pressure_pa: Levels,
    /// Time an instrument's mean pressure stayed at or above
    /// `pressure_pa.warn`, s.
    pub time_above_s: Levels,
    /// An instrument's mean pressure integrated over the session, Pa s.
    pub pressure_time_pa_s: Levels,
    /// Largest principal Green-Lagrange strain of the tissue.
    pub strain: Levels,
    /// Tissue volume at or above `strain.warn`, m^3.
    pub strained_volume_m3: Levels,
}

impl Default for AssessmentSpec {
    fn default() -> Self {
        Self {
            pressure_pa: Levels {
                warn: 20.0 * PA_PER_MMHG,
                fail: 30.0 * PA_PER_MMHG,
            },
            time_above_s: Levels {
                warn: 300.0,
                fail: 900.0,
            },
            pressure_time_pa_s: Levels {
                warn: 100.0 * PA_PER_MMHG * 60.0,
                fail: 300.0 * PA_PER_MMHG * 60.0,
            },
            strain: Levels {
                warn: 0.14,
                fail: 0.21,
            },
            strained_volume_m3: Levels {
                warn: 1e-9,
                fail: 1e-7,
            },
        }
    }
}

impl AssessmentSpec {
    /// Every pair of levels with its field name.
    pub fn levels(&self) -> [(&'static str, Levels); 5] {
        [
            ("pressure_pa", self.pressure_pa),
            ("time_above_s", self.time_above_s),
            ("pressure_time_pa_s", self.pressure_time_pa_s),
            ("strain", self.strain),
            ("strained_volume_m3", self.strained_volume_m3),
        ]
    }

    /// Checks every level: finite, positive, `warn <= fail`. The error is
    /// the field (`assessment.strain.warn`) and what is wrong.
    pub fn check(&self) -> Result<(), (String, String)> {
        for (name, l) in self.levels() {
            for (which, v) in [("warn", l.warn), ("fail", l.fail)] {
                if !(v.is_finite() && v > 0.0) {
                    return Err((
                        format!("assessment.{name}.{which}"),
                        format!("must be a finite positive number, got {v}"),
                    ));
                }
            }
            if l.warn > l.fail {
                return Err((
                    format!("assessment.{name}"),
                    format!("warn ({}) must not be above fail ({})", l.warn, l.fail),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A value exactly at a level takes that level's grade.
    #[test]
    fn a_value_at_a_level_takes_its_grade() {
        let l = Levels {
            warn: 1.0,
            fail: 2.0,
        };
        assert_eq!(l.grade(0.999), Grade::Pass);
        assert_eq!(l.grade(1.0), Grade::Warn);
        assert_eq!(l.grade(2.0), Grade::Fail);
        assert_eq!(l.grade(f64::INFINITY), Grade::Fail);
    }

    /// The defaults are the cited values: 20 and 30 mmHg, 300 mmHg min.
    #[test]
    fn the_defaults_are_the_cited_values() {
        let a = AssessmentSpec::default();
        assert!((a.pressure_pa.warn - 2666.4477).abs() < 1e-3);
        assert!((a.pressure_pa.fail / PA_PER_MMHG - 30.0).abs() < 1e-12);
        assert!((a.pressure_time_pa_s.fail / (PA_PER_MMHG * 60.0) - 300.0).abs() < 1e-9);
        assert!(a.check().is_ok());
    }

    /// A warning above its failing level is named.
    #[test]
    fn a_warning_above_its_failure_is_named() {
        let mut a = AssessmentSpec::default();
        a.strain.warn = 0.5;
        let (field, reason) = a.check().unwrap_err();
        assert_eq!(field, "assessment.strain");
        assert!(reason.contains("0.5"), "{reason}");
        a = AssessmentSpec::default();
        a.time_above_s.fail = f64::NAN;
        assert_eq!(a.check().unwrap_err().0, "assessment.time_above_s.fail");
    }
}
