//! What a session did to the brain, from its recording: each injury measure
//! of the frames (the server's `sim::core::injury`) at its worst, scored
//! against the scene's thresholds (`[assessment]`, carried in the
//! recording's header; the cited defaults for a recording without them),
//! and the events a teacher looks for (ties cut and torn, vessels torn,
//! forces clamped, pose jumps).
//!
//! The session sums of the pressure (time above the warning pressure, the
//! pressure-time product) are the engine's, read from the frames: a reset
//! starts them again, so the session's sum adds each run's last value.

use fissure_proto::v1 as pb;
use fissure_shared::assessment::{AssessmentSpec, Grade, Levels, PA_PER_MMHG};

/// One measure against its levels.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Score {
    /// What is measured, e.g. `mean retraction pressure`.
    pub measure: String,
    /// The instrument it is of (none: the tissue's or the session's).
    pub instrument: Option<String>,
    /// The value, in SI units (`unit`).
    pub value: f64,
    /// The SI unit of `value` and the levels.
    pub unit: &'static str,
    /// Its levels (`fail` infinite: the measure only warns).
    pub levels: Levels,
    /// Where the value stands.
    pub grade: Grade,
}

impl Score {
    fn new(
        measure: &str,
        instrument: Option<&str>,
        value: f64,
        unit: &'static str,
        levels: Levels,
    ) -> Self {
        Self {
            measure: measure.to_owned(),
            instrument: instrument.map(str::to_owned),
            value,
            unit,
            levels,
            grade: levels.grade(value),
        }
    }

    /// `value` as a person reads it (pressures in mmHg and kPa, products in
    /// mmHg min, volumes in mm^3, times in s).
    pub fn shown(&self, v: f64) -> String {
        if !v.is_finite() {
            return "—".into();
        }
        match self.unit {
            "Pa" => format!("{:.1} mmHg ({:.2} kPa)", v / PA_PER_MMHG, v / 1e3),
            "Pa s" => format!("{:.1} mmHg min", v / (PA_PER_MMHG * 60.0)),
            "m^3" => format!("{:.2} mm³", v * 1e9),
            "s" => format!("{v:.2} s"),
            "N" => format!("{v:.3} N"),
            "" => format!("{v:.3}"),
            _ => format!("{v}"),
        }
    }
}

/// The pressure under one instrument over the session.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct PressureReport {
    /// Instrument name.
    pub instrument: String,
    /// Largest mean pressure of a frame, Pa.
    pub peak_mean_pa: f64,
    /// Its time, s.
    pub peak_mean_t_s: f64,
    /// Largest vertex pressure of a frame, Pa.
    pub peak_vertex_pa: f64,
    /// Largest contact area of a frame, m^2.
    pub peak_contact_area_m2: f64,
    /// Time with the mean pressure at or above the warning pressure, s.
    pub time_above_s: f64,
    /// Mean pressure integrated over the session, Pa s.
    pub pressure_time_pa_s: f64,
}

/// The tissue's strain over the session.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct StrainReport {
    /// Largest principal Green-Lagrange strain of a frame.
    pub peak: f64,
    /// Its time, s.
    pub peak_t_s: f64,
    /// Where (rest position of its tetrahedron), m.
    pub at_m: [f64; 3],
    /// Largest tissue volume at or above the warning strain, m^3.
    pub peak_volume_m3: f64,
}

/// Something that happened, with its time.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EventReport {
    /// Simulation time, s.
    pub t_s: f64,
    /// The instrument involved (empty: none).
    pub instrument: String,
    /// What happened.
    pub what: String,
    /// Whether it is an injury (a torn vessel).
    pub injury: bool,
}

/// Force samples flagged, per flag, over all instruments.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SafetyCounts {
    /// Samples whose force was clamped to the scene's maximum.
    pub force_clamped: usize,
    /// Samples whose pose jumped farther than the scene allows.
    pub pose_jumps: usize,
}

/// The assessment of a session.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Assessment {
    /// The levels scored against.
    pub thresholds: AssessmentSpec,
    /// Whether they are the scene's (false: the recording carries none and
    /// the defaults are used).
    pub thresholds_from_scene: bool,
    /// The pressure under each instrument.
    pub pressure: Vec<PressureReport>,
    /// The tissue's strain.
    pub strain: StrainReport,
    /// Force samples flagged.
    pub safety: SafetyCounts,
    /// Ties released, vessels torn, forces clamped and poses jumped, by
    /// time.
    pub events: Vec<EventReport>,
    /// Every measure against its levels.
    pub scores: Vec<Score>,
    /// The worst grade.
    pub grade: Option<Grade>,
}

/// Levels of a measure that only warns (at `warn`).
fn warn_only(warn: f64) -> Levels {
    Levels {
        warn,
        fail: f64::INFINITY,
    }
}

fn levels(l: &Option<pb::Levels>, default: Levels) -> Levels {
    l.as_ref().map_or(default, |l| Levels {
        warn: l.warn,
        fail: l.fail,
    })
}

/// The scene's thresholds from a recording header (the defaults for those
/// it does not carry), and whether it carried them.
pub fn thresholds(scene: Option<&pb::SceneDescription>) -> (AssessmentSpec, bool) {
    let d = AssessmentSpec::default();
    match scene.and_then(|s| s.assessment.as_ref()) {
        Some(a) => (
            AssessmentSpec {
                pressure_pa: levels(&a.pressure_pa, d.pressure_pa),
                time_above_s: levels(&a.time_above_s, d.time_above_s),
                pressure_time_pa_s: levels(&a.pressure_time_pa_s, d.pressure_time_pa_s),
                strain: levels(&a.strain, d.strain),
                strained_volume_m3: levels(&a.strained_volume_m3, d.strained_volume_m3),
            },
            true,
        ),
        None => (d, false),
    }
}

/// A session's sum of a quantity the engine sums from each reset: the sum
/// of each run's last value (a run ends where the value falls).
#[derive(Debug, Clone, Copy, Default)]
struct RunSum {
    done: f64,
    last: f64,
}

impl RunSum {
    fn add(&mut self, v: f64) {
        if v < self.last {
            self.done += self.last;
        }
        self.last = v;
    }

    fn total(&self) -> f64 {
        self.done + self.last
    }
}

/// Builds the assessment while the recording is read: frames and force
/// samples in the order recorded.
#[derive(Debug, Default)]
pub struct Assessor {
    a: Assessment,
    sums: Vec<(RunSum, RunSum)>,
    flags: std::collections::BTreeMap<String, u32>,
}

impl Assessor {
    /// An assessment against `thresholds` (`from_scene`: the recording's).
    pub fn new(thresholds: AssessmentSpec, from_scene: bool) -> Self {
        Self {
            a: Assessment {
                thresholds,
                thresholds_from_scene: from_scene,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    /// A recorded frame.
    pub fn frame(&mut self, f: &pb::DeformationFrame) {
        let t = f.sim_time_s;
        for (k, r) in f.instruments.iter().enumerate() {
            let Some(p) = &r.pressure else {
                continue;
            };
            while self.a.pressure.len() <= k {
                self.a.pressure.push(PressureReport::default());
                self.sums.push(Default::default());
            }
            let out = &mut self.a.pressure[k];
            out.instrument.clone_from(&r.name);
            if p.mean_pa > out.peak_mean_pa {
                out.peak_mean_pa = p.mean_pa;
                out.peak_mean_t_s = t;
            }
            out.peak_vertex_pa = out.peak_vertex_pa.max(p.peak_pa);
            out.peak_contact_area_m2 = out.peak_contact_area_m2.max(p.contact_area_m2);
            let (above, product) = &mut self.sums[k];
            above.add(p.time_above_s);
            product.add(p.pressure_time_pa_s);
            out.time_above_s = above.total();
            out.pressure_time_pa_s = product.total();
        }
        if let Some(s) = &f.strain {
            let out = &mut self.a.strain;
            if s.max_principal > out.peak {
                out.peak = s.max_principal;
                out.peak_t_s = t;
                out.at_m = s.at_m.map_or([0.0; 3], |p| [p.x, p.y, p.z]);
            }
            out.peak_volume_m3 = out.peak_volume_m3.max(s.volume_above_m3);
        }
        if let Some(ties) = &f.ties {
            for e in &ties.events {
                let vessel = e.kind() == pb::TieKind::Vessel;
                let cut = e.cause() == pb::TieCause::Cut;
                self.a.events.push(EventReport {
                    t_s: e.sim_time_s,
                    instrument: e.instrument.clone(),
                    what: format!(
                        "{} {} {}",
                        if vessel { "vessel" } else { "trabecula" },
                        e.tie,
                        if cut { "cut" } else { "torn" }
                    ),
                    injury: vessel && !cut,
                });
            }
        }
    }

    /// A recorded force sample of `instrument`.
    pub fn force(&mut self, instrument: &str, s: &pb::ForceSample) {
        let before = self.flags.get(instrument).copied().unwrap_or(0);
        let now = s.safety_flags;
        let onset = now & !before;
        for (flag, what) in [
            (
                pb::SafetyFlag::ForceClamped,
                "force clamped to the scene's maximum",
            ),
            (
                pb::SafetyFlag::PoseJump,
                "pose jumped farther than the scene allows",
            ),
        ] {
            let bit = flag as u32;
            if now & bit != 0 {
                match flag {
                    pb::SafetyFlag::ForceClamped => self.a.safety.force_clamped += 1,
                    _ => self.a.safety.pose_jumps += 1,
                }
            }
            if onset & bit != 0 {
                self.a.events.push(EventReport {
                    t_s: s.t_s,
                    instrument: instrument.to_owned(),
                    what: what.into(),
                    injury: false,
                });
            }
        }
        self.flags.insert(instrument.to_owned(), now);
    }

    /// The assessment, scored; `peak_force` is each instrument's largest
    /// force (N) and `threshold_n` the safe force it warns at.
    pub fn finish(mut self, peak_force: &[(String, f64)], threshold_n: f64) -> Assessment {
        let a = &mut self.a;
        a.events.sort_by(|x, y| x.t_s.total_cmp(&y.t_s));
        let th = a.thresholds;
        let mut scores = Vec::new();
        for (name, f) in peak_force {
            scores.push(Score::new(
                "peak force",
                Some(name),
                *f,
                "N",
                warn_only(threshold_n),
            ));
        }
        for p in &a.pressure {
            let i = Some(p.instrument.as_str());
            scores.push(Score::new(
                "peak mean retraction pressure",
                i,
                p.peak_mean_pa,
                "Pa",
                th.pressure_pa,
            ));
            scores.push(Score::new(
                "time above the warning pressure",
                i,
                p.time_above_s,
                "s",
                th.time_above_s,
            ));
            scores.push(Score::new(
                "pressure-time product",
                i,
                p.pressure_time_pa_s,
                "Pa s",
                th.pressure_time_pa_s,
            ));
        }
        scores.push(Score::new(
            "peak principal strain",
            None,
            a.strain.peak,
            "",
            th.strain,
        ));
        scores.push(Score::new(
            "tissue volume above the warning strain",
            None,
            a.strain.peak_volume_m3,
            "m^3",
            th.strained_volume_m3,
        ));
        let count = |pred: &dyn Fn(&EventReport) -> bool| {
            a.events.iter().filter(|e| pred(e)).count() as f64
        };
        scores.push(Score::new(
            "vessels torn",
            None,
            count(&|e| e.injury),
            "count",
            Levels {
                warn: 1.0,
                fail: 1.0,
            },
        ));
        scores.push(Score::new(
            "trabeculae torn",
            None,
            count(&|e| e.what.starts_with("trabecula") && e.what.ends_with("torn")),
            "count",
            warn_only(1.0),
        ));
        scores.push(Score::new(
            "force samples clamped",
            None,
            a.safety.force_clamped as f64,
            "count",
            warn_only(1.0),
        ));
        scores.push(Score::new(
            "pose jumps",
            None,
            a.safety.pose_jumps as f64,
            "count",
            warn_only(1.0),
        ));
        a.grade = scores.iter().map(|s| s.grade).max();
        a.scores = scores;
        self.a
    }
}

/// A measure reaching a level during a session: what a live watcher or a
/// bridge tells the trainee.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Alert {
    /// Simulation time of the frame, s.
    pub t_s: f64,
    /// What is measured.
    pub measure: &'static str,
    /// The instrument (none: the tissue).
    pub instrument: Option<String>,
    /// The value, SI (`unit`).
    pub value: f64,
    /// The SI unit.
    pub unit: &'static str,
    /// The level reached: `warn` or `fail`.
    pub grade: Grade,
    /// That level's value, SI.
    pub level: f64,
}

impl Alert {
    /// One line, ASCII (it goes into OpenIGTLink STATUS texts): `t =
    /// 1.230 s: left: mean retraction pressure 21.4 mmHg (2.85 kPa)
    /// reached warn (20.0 mmHg (2.67 kPa))`.
    pub fn line(&self) -> String {
        let shown = Score::new(self.measure, None, self.value, self.unit, warn_only(1.0));
        let who = self
            .instrument
            .as_deref()
            .map_or(String::new(), |i| format!("{i}: "));
        format!(
            "t = {:.3} s: {who}{} {} reached {} ({})",
            self.t_s,
            self.measure,
            shown.shown(self.value),
            self.grade.name(),
            shown.shown(self.level)
        )
        .replace('³', "^3")
    }
}

/// Reads a session's frames as they come and says when a measure first
/// reaches its warning level, then its failing level (once each per
/// measure and instrument; a reset of the session does not repeat them).
#[derive(Debug, Clone, Default)]
pub struct LiveAlerts {
    thresholds: AssessmentSpec,
    reached: std::collections::BTreeMap<(&'static str, Option<String>), Grade>,
}

impl LiveAlerts {
    /// Alerts against `thresholds`.
    pub fn new(thresholds: AssessmentSpec) -> Self {
        Self {
            thresholds,
            reached: Default::default(),
        }
    }

    /// The alerts of frame `f`.
    pub fn frame(&mut self, f: &pb::DeformationFrame) -> Vec<Alert> {
        let th = self.thresholds;
        let mut values: Vec<(&'static str, Option<String>, f64, &'static str, Levels)> = Vec::new();
        for r in &f.instruments {
            if let Some(p) = &r.pressure {
                let i = Some(r.name.clone());
                values.push((
                    "mean retraction pressure",
                    i.clone(),
                    p.mean_pa,
                    "Pa",
                    th.pressure_pa,
                ));
                values.push((
                    "time above the warning pressure",
                    i.clone(),
                    p.time_above_s,
                    "s",
                    th.time_above_s,
                ));
                values.push((
                    "pressure-time product",
                    i,
                    p.pressure_time_pa_s,
                    "Pa s",
                    th.pressure_time_pa_s,
                ));
            }
        }
        if let Some(s) = &f.strain {
            values.push(("principal strain", None, s.max_principal, "", th.strain));
            values.push((
                "tissue volume above the warning strain",
                None,
                s.volume_above_m3,
                "m^3",
                th.strained_volume_m3,
            ));
        }
        let mut out = Vec::new();
        for (measure, instrument, value, unit, levels) in values {
            let grade = levels.grade(value);
            let key = (measure, instrument.clone());
            let before = self.reached.get(&key).copied().unwrap_or(Grade::Pass);
            if grade > before {
                self.reached.insert(key, grade);
                out.push(Alert {
                    t_s: f.sim_time_s,
                    measure,
                    instrument,
                    value,
                    unit,
                    grade,
                    level: if grade == Grade::Fail {
                        levels.fail
                    } else {
                        levels.warn
                    },
                });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t: f64, mean_pa: f64, above: f64, product: f64, strain: f64) -> pb::DeformationFrame {
        pb::DeformationFrame {
            sim_time_s: t,
            instruments: vec![pb::InstrumentReaction {
                name: "left".into(),
                pressure: Some(pb::RetractionPressure {
                    mean_pa,
                    peak_pa: 2.0 * mean_pa,
                    time_above_s: above,
                    pressure_time_pa_s: product,
                    ..Default::default()
                }),
                ..Default::default()
            }],
            strain: Some(pb::TissueStrain {
                max_principal: strain,
                volume_above_m3: if strain >= 0.14 { 2e-9 } else { 0.0 },
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    /// Sums across a reset add each run's last value; peaks are the
    /// session's; the grades follow the levels.
    #[test]
    fn sums_survive_a_reset_and_peaks_are_graded() {
        let mut a = Assessor::new(AssessmentSpec::default(), true);
        a.frame(&frame(0.0, 0.0, 0.0, 0.0, 0.0));
        a.frame(&frame(1.0, 3000.0, 0.0, 0.0, 0.05));
        a.frame(&frame(2.0, 1000.0, 1.0, 3000.0, 0.15));
        // A reset: the engine's sums start again.
        a.frame(&frame(3.0, 500.0, 0.0, 0.0, 0.01));
        a.frame(&frame(4.0, 0.0, 0.0, 500.0, 0.0));
        let r = a.finish(&[("left".into(), 0.5)], 1.0);
        let p = &r.pressure[0];
        assert_eq!(p.peak_mean_pa, 3000.0);
        assert_eq!(p.peak_mean_t_s, 1.0);
        assert_eq!(p.peak_vertex_pa, 6000.0);
        assert_eq!(p.time_above_s, 1.0);
        assert_eq!(p.pressure_time_pa_s, 3500.0);
        assert_eq!(r.strain.peak, 0.15);
        assert_eq!(r.strain.peak_volume_m3, 2e-9);
        let grade = |m: &str| r.scores.iter().find(|s| s.measure == m).unwrap().grade;
        // 3000 Pa = 22.5 mmHg: above 20, below 30.
        assert_eq!(grade("peak mean retraction pressure"), Grade::Warn);
        assert_eq!(grade("peak principal strain"), Grade::Warn);
        assert_eq!(grade("tissue volume above the warning strain"), Grade::Warn);
        assert_eq!(grade("peak force"), Grade::Pass);
        assert_eq!(grade("vessels torn"), Grade::Pass);
        assert_eq!(r.grade, Some(Grade::Warn));
    }

    /// A flag counts every sample it is on, and is an event where it comes
    /// on.
    #[test]
    fn flags_count_samples_and_their_onsets_are_events() {
        let mut a = Assessor::new(AssessmentSpec::default(), false);
        let clamped = pb::SafetyFlag::ForceClamped as u32;
        for (k, flags) in [0, clamped, clamped, 0, clamped].into_iter().enumerate() {
            a.force(
                "left",
                &pb::ForceSample {
                    t_s: k as f64 * 1e-3,
                    safety_flags: flags,
                    ..Default::default()
                },
            );
        }
        let r = a.finish(&[], 1.0);
        assert_eq!(r.safety.force_clamped, 3);
        let times: Vec<f64> = r.events.iter().map(|e| e.t_s).collect();
        assert_eq!(times, [1e-3, 4e-3]);
    }

    /// Each measure alerts once at its warning level and once at its
    /// failing level, whatever comes after.
    #[test]
    fn a_measure_alerts_once_per_level() {
        let mut live = LiveAlerts::new(AssessmentSpec::default());
        let grades = |live: &mut LiveAlerts, f: &pb::DeformationFrame| {
            live.frame(f)
                .iter()
                .map(|a| (a.measure, a.grade))
                .collect::<Vec<_>>()
        };
        assert!(grades(&mut live, &frame(0.0, 100.0, 0.0, 0.0, 0.01)).is_empty());
        assert_eq!(
            grades(&mut live, &frame(0.1, 3000.0, 0.0, 0.0, 0.15)),
            [
                ("mean retraction pressure", Grade::Warn),
                ("principal strain", Grade::Warn),
                ("tissue volume above the warning strain", Grade::Warn)
            ]
        );
        assert!(grades(&mut live, &frame(0.2, 3100.0, 0.1, 0.0, 0.16)).is_empty());
        assert_eq!(
            grades(&mut live, &frame(0.3, 4500.0, 0.2, 0.0, 0.1)),
            [("mean retraction pressure", Grade::Fail)]
        );
        let a = &live.frame(&frame(0.4, 0.0, 0.0, 0.0, 0.3))[0];
        assert_eq!(a.grade, Grade::Fail);
        assert!(
            a.line()
                .contains("principal strain 0.300 reached fail (0.210)"),
            "{}",
            a.line()
        );
        // Volumes are written mm^3 in a line (ASCII).
        let mut big = frame(0.6, 0.0, 0.0, 0.0, 0.3);
        big.strain.as_mut().unwrap().volume_above_m3 = 2e-7;
        let line = live.frame(&big)[0].line();
        assert!(line.is_ascii() && line.contains("200.00 mm^3"), "{line}");
    }
}
