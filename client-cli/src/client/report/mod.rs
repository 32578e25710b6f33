//! `fissure report`: a summary of a session recording (forces, motion, ties),
//! its assessment ([`assess`]: what the session did to the brain, scored
//! against the scene's thresholds), the page a teacher opens ([`html`]),
//! and the trajectories it holds (for `fissure replay --recording`).

pub mod assess;
pub mod html;

use crate::client::trajectory::{Trajectory, Waypoint};
use fissure_proto::recording;
use fissure_proto::v1 as pb;
use std::collections::BTreeMap;
use std::path::Path;

/// Summary of one instrument in a recording.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct InstrumentReport {
    /// Instrument name.
    pub instrument: String,
    /// Force samples.
    pub samples: usize,
    /// Time from its first to its last pose, s.
    pub duration_s: f64,
    /// Largest force magnitude, N.
    pub peak_force_n: f64,
    /// Mean force magnitude over the samples in contact, N.
    pub mean_force_in_contact_n: f64,
    /// Time with the force magnitude above the threshold, s.
    pub time_above_threshold_s: f64,
    /// Length of the handle's path, m.
    pub path_length_m: f64,
    /// Time with at least one contact vertex, s.
    pub time_in_contact_s: f64,
}

/// Entries the recorder dropped (its queue to the disk was full), by kind,
/// and the places in the file where they are missing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LostEntries {
    /// Accepted poses not recorded.
    pub poses: u64,
    /// Force samples not recorded.
    pub forces: u64,
    /// Frame summaries not recorded.
    pub frames: u64,
    /// Gap entries: places where entries are missing.
    pub gaps: usize,
}

impl LostEntries {
    /// All kinds together.
    pub fn total(&self) -> u64 {
        self.poses + self.forces + self.frames
    }
}

/// The rigid part of the recorded frame with the largest surface
/// displacement (the server's best fit over the surface vertices).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct MotionReport {
    /// Frame number.
    pub frame: u64,
    /// Its largest surface displacement, m.
    pub max_displacement_m: f64,
    /// Best-fit rotation angle, degrees.
    pub rotation_deg: f64,
    /// Best-fit translation of the surface centroid, m.
    pub translation_m: f64,
    /// Largest rigid displacement of a surface vertex, m.
    pub max_rigid_m: f64,
    /// Radius of "near the instruments' tips", m.
    pub near_radius_m: f64,
    /// Largest non-rigid displacement within that radius, m.
    pub max_non_rigid_near_m: f64,
    /// Largest non-rigid displacement beyond it, m.
    pub max_non_rigid_far_m: f64,
}

impl MotionReport {
    /// The rigid part `frame` carries, if it carries one.
    pub fn of(frame: &pb::DeformationFrame) -> Option<Self> {
        let r = frame.rigid.as_ref()?;
        let t = r.translation_m.unwrap_or_default();
        Some(Self {
            frame: frame.frame,
            max_displacement_m: frame.max_displacement_m,
            rotation_deg: r.rotation_deg,
            translation_m: (t.x * t.x + t.y * t.y + t.z * t.z).sqrt(),
            max_rigid_m: r.max_rigid_m,
            near_radius_m: r.near_radius_m,
            max_non_rigid_near_m: r.max_non_rigid_near_m,
            max_non_rigid_far_m: r.max_non_rigid_far_m,
        })
    }

    /// Two lines of text: the rigid part, and the non-rigid displacement
    /// near the tips and beyond (the demo's summary and `fissure report`).
    pub fn lines(&self) -> String {
        let pct = |a: f64, b: f64| if b > 0.0 { 100.0 * a / b } else { 0.0 };
        format!(
            "rigid part of that frame (best fit over the surface): rotation {:.3} deg, translation {:.3} mm; largest rigid displacement {:.2} mm ({:.1} % of the largest)\n\
             largest non-rigid displacement: {:.2} mm within {:.0} mm of the tips, {:.2} mm beyond ({:.1} % of the near one)\n",
            self.rotation_deg,
            self.translation_m * 1e3,
            self.max_rigid_m * 1e3,
            pct(self.max_rigid_m, self.max_displacement_m),
            self.max_non_rigid_near_m * 1e3,
            self.near_radius_m * 1e3,
            self.max_non_rigid_far_m * 1e3,
            pct(self.max_non_rigid_far_m, self.max_non_rigid_near_m),
        )
    }
}

/// Summary of a recording.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Report {
    /// Scene name.
    pub scene: String,
    /// Time from the first to the last pose of any instrument, s.
    pub duration_s: f64,
    /// Deformation frames recorded.
    pub frames: usize,
    /// Frames whose step failed.
    pub failed_frames: usize,
    /// Safe-force threshold used, N.
    pub threshold_n: f64,
    /// Whether the file ended in a truncated entry (a crash mid-write).
    pub truncated: bool,
    /// Entries the recorder dropped; the per-instrument figures cover only
    /// what was recorded.
    pub lost: LostEntries,
    /// Per instrument.
    pub instruments: Vec<InstrumentReport>,
    /// The rigid part of the frame with the largest displacement (absent
    /// in recordings without it).
    pub motion: Option<MotionReport>,
    /// The ties across the fissure (absent when the scene has none).
    pub ties: Option<TieReport>,
    /// What the session did to the brain, scored.
    pub assessment: assess::Assessment,
    /// The curves and the picture the page draws (left out of the JSON).
    #[serde(skip)]
    pub traces: Traces,
}

/// What the page draws of a session.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Traces {
    /// The scene as recorded.
    pub scene: Option<pb::SceneDescription>,
    /// The rest surface (recordings of this version on).
    pub surface: Option<pb::SurfaceMesh>,
    /// Per instrument: time (s) and force magnitude (N) of its samples.
    pub force: Vec<(String, Vec<[f64; 2]>)>,
    /// Per instrument: time (s) and mean retraction pressure (Pa) of the
    /// frames.
    pub pressure: Vec<(String, Vec<[f64; 2]>)>,
    /// Time (s) and largest principal strain of the frames.
    pub strain: Vec<[f64; 2]>,
    /// The frame of the worst strain picture, its positions the picture's.
    pub worst: Option<pb::DeformationFrame>,
}

/// How to read a recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Safe-force threshold, N.
    pub threshold_n: f64,
    /// Report what precedes a truncated last entry instead of refusing
    /// the file.
    pub accept_truncated: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            threshold_n: 1.0,
            accept_truncated: false,
        }
    }
}

/// What became of the ties over a recording.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct TieReport {
    /// Intact trabeculae and vessels in the first frame.
    pub first: (u32, u32),
    /// In the last frame.
    pub last: (u32, u32),
    /// Every tie released, in order.
    pub events: Vec<TieEventReport>,
}

/// One tie released.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TieEventReport {
    /// Simulation time, s.
    pub t_s: f64,
    /// The tie's index in the scene.
    pub tie: u32,
    /// `trabecula` or `vessel`.
    pub kind: &'static str,
    /// `cut` or `torn`.
    pub cause: &'static str,
    /// The instrument that cut or tore it.
    pub instrument: String,
    /// Its midpoint, m.
    pub position_m: [f64; 3],
    /// Its strain when it went.
    pub strain: f64,
}

impl TieReport {
    fn add(report: &mut Option<Self>, t: &pb::TieSummary) {
        let counts = (t.trabeculae_intact, t.vessels_intact);
        let r = report.get_or_insert_with(|| TieReport {
            first: counts,
            ..Default::default()
        });
        r.last = counts;
        r.events.extend(t.events.iter().map(|e| TieEventReport {
            t_s: e.sim_time_s,
            tie: e.tie,
            kind: match e.kind() {
                pb::TieKind::Vessel => "vessel",
                _ => "trabecula",
            },
            cause: match e.cause() {
                pb::TieCause::Cut => "cut",
                _ => "torn",
            },
            instrument: e.instrument.clone(),
            position_m: e.position_m.map_or([0.0; 3], |p| [p.x, p.y, p.z]),
            strain: e.strain,
        }));
    }

    fn lines(&self) -> String {
        let count = |kind: &str, cause: &str| {
            self.events
                .iter()
                .filter(|e| e.kind == kind && e.cause == cause)
                .count()
        };
        let mut s = format!(
            "ties: trabeculae {} -> {} intact ({} cut, {} torn); vessels {} -> {} intact ({} cut, {} torn{})\n",
            self.first.0,
            self.last.0,
            count("trabecula", "cut"),
            count("trabecula", "torn"),
            self.first.1,
            self.last.1,
            count("vessel", "cut"),
            count("vessel", "torn"),
            if count("vessel", "torn") > 0 {
                ": an injury"
            } else {
                ""
            }
        );
        for e in &self.events {
            s.push_str(&format!(
                "  t {:>8.3} s  {:<9} {:>5} {:<4} by {:<10} at ({:.1}, {:.1}, {:.1}) mm, strain {:.3}\n",
                e.t_s,
                e.kind,
                e.tie,
                e.cause,
                e.instrument,
                e.position_m[0] * 1e3,
                e.position_m[1] * 1e3,
                e.position_m[2] * 1e3,
                e.strain
            ));
        }
        s
    }
}

fn norm(v: &Option<pb::Vec3>) -> f64 {
    v.as_ref()
        .map_or(0.0, |v| (v.x * v.x + v.y * v.y + v.z * v.z).sqrt())
}

/// Reads a recording and summarises it; `threshold_n` is the safe-force
/// threshold. A truncated last entry is an error naming its byte offset.
pub fn report(path: &Path, threshold_n: f64) -> anyhow::Result<Report> {
    report_with(
        path,
        &Options {
            threshold_n,
            ..Default::default()
        },
    )
}

/// Reads a recording and summarises it.
pub fn report_with(path: &Path, options: &Options) -> anyhow::Result<Report> {
    let threshold_n = options.threshold_n;
    let rec = recording::read_recording(path)?;
    if let (Some(at), false) = (rec.truncated_at, options.accept_truncated) {
        anyhow::bail!(
            "{}: the recording is truncated: its last entry, at byte {at}, is cut short \
             (the recorder stopped mid-write); `--accept-truncated` reports the entries before it",
            path.display()
        );
    }
    let lost = rec.lost();
    let lost = LostEntries {
        poses: lost.poses,
        forces: lost.forces,
        frames: lost.frames,
        gaps: rec.gaps.len(),
    };
    let truncated = rec.truncated;
    let mut scene = String::new();
    let mut frames = 0;
    let mut failed_frames = 0;
    let mut motion: Option<MotionReport> = None;
    let mut ties: Option<TieReport> = None;
    let mut forces: BTreeMap<String, Vec<pb::ForceSample>> = BTreeMap::new();
    let mut poses: BTreeMap<String, Vec<pb::PoseSample>> = BTreeMap::new();
    let mut assessor = assess::Assessor::new(Default::default(), false);
    let mut traces = Traces::default();
    for e in rec.entries {
        match e.entry {
            Some(pb::recording_entry::Entry::Header(h)) => {
                let (thresholds, from_scene) = assess::thresholds(h.scene.as_ref());
                assessor = assess::Assessor::new(thresholds, from_scene);
                scene = h.scene.as_ref().map(|s| s.name.clone()).unwrap_or_default();
                traces.scene = h.scene;
                traces.surface = h.surface;
            }
            Some(pb::recording_entry::Entry::Pose(p)) => {
                poses.entry(p.instrument).or_default().extend(p.pose);
            }
            Some(pb::recording_entry::Entry::Force(f)) => {
                if let Some(s) = &f.sample {
                    assessor.force(&f.instrument, s);
                }
                forces.entry(f.instrument).or_default().extend(f.sample);
            }
            Some(pb::recording_entry::Entry::Frame(mut f)) => {
                frames += 1;
                if let Some(m) = MotionReport::of(&f) {
                    if motion.is_none_or(|best| m.max_displacement_m > best.max_displacement_m) {
                        motion = Some(m);
                    }
                }
                if !f.solver_error.is_empty() {
                    failed_frames += 1;
                }
                if let Some(t) = &f.ties {
                    TieReport::add(&mut ties, t);
                }
                assessor.frame(&f);
                traces.add_frame(&mut f);
            }
            // Gaps are in `rec.gaps`; `None`: a member of a later version.
            Some(pb::recording_entry::Entry::Gap(_)) | None => {}
        }
    }
    let (mut t_min, mut t_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut instruments = Vec::new();
    for (name, samples) in &forces {
        let mut r = InstrumentReport {
            instrument: name.clone(),
            samples: samples.len(),
            ..Default::default()
        };
        let mut in_contact = (0.0, 0usize);
        for (i, s) in samples.iter().enumerate() {
            let f = norm(&s.force_n);
            r.peak_force_n = r.peak_force_n.max(f);
            if s.contact_count > 0 {
                in_contact.0 += f;
                in_contact.1 += 1;
            }
            // Each sample holds until the next one.
            if let Some(next) = samples.get(i + 1) {
                let dt = (next.t_s - s.t_s).max(0.0);
                if f > threshold_n {
                    r.time_above_threshold_s += dt;
                }
                if s.contact_count > 0 {
                    r.time_in_contact_s += dt;
                }
            }
        }
        r.mean_force_in_contact_n = if in_contact.1 > 0 {
            in_contact.0 / in_contact.1 as f64
        } else {
            0.0
        };
        if let Some(ps) = poses.get(name) {
            if let (Some(a), Some(b)) = (ps.first(), ps.last()) {
                r.duration_s = b.t_s - a.t_s;
                t_min = t_min.min(a.t_s);
                t_max = t_max.max(b.t_s);
            }
            r.path_length_m = ps
                .windows(2)
                .map(|w| {
                    let (a, b) = (
                        w[0].position_m.unwrap_or_default(),
                        w[1].position_m.unwrap_or_default(),
                    );
                    ((b.x - a.x).powi(2) + (b.y - a.y).powi(2) + (b.z - a.z).powi(2)).sqrt()
                })
                .sum();
        }
        instruments.push(r);
        traces.force.push((
            name.clone(),
            samples.iter().map(|s| [s.t_s, norm(&s.force_n)]).collect(),
        ));
    }
    let peaks: Vec<(String, f64)> = instruments
        .iter()
        .map(|i| (i.instrument.clone(), i.peak_force_n))
        .collect();
    Ok(Report {
        scene,
        duration_s: if t_max >= t_min { t_max - t_min } else { 0.0 },
        frames,
        failed_frames,
        threshold_n,
        truncated,
        lost,
        instruments,
        motion,
        ties,
        assessment: assessor.finish(&peaks, threshold_n),
        traces,
    })
}

impl Traces {
    /// Takes what the page draws of frame `f` (its strain picture moves
    /// into [`Traces::worst`] when it is the worst so far).
    fn add_frame(&mut self, f: &mut pb::DeformationFrame) {
        let t = f.sim_time_s;
        for (k, r) in f.instruments.iter().enumerate() {
            if self.pressure.len() <= k {
                self.pressure.push((r.name.clone(), Vec::new()));
            }
            let p = r.pressure.as_ref().map_or(0.0, |p| p.mean_pa);
            self.pressure[k].1.push([t, p]);
        }
        let Some(strain) = f.strain.as_mut() else {
            return;
        };
        self.strain.push([t, strain.max_principal]);
        let worst = self
            .worst
            .as_ref()
            .and_then(|w| w.strain.as_ref())
            .map_or(f64::NEG_INFINITY, |s| s.max_principal);
        if strain.max_principal > worst {
            if let Some(picture) = strain.picture.take() {
                let mut w = f.clone();
                w.positions_m = picture.positions_m.clone();
                if let Some(s) = w.strain.as_mut() {
                    s.picture = Some(picture);
                }
                self.worst = Some(w);
            }
        }
    }
}

/// `fissure report`: reads `file` (and `compare`, an expert's session to
/// put beside it), and gives the text to print: the tables, or with `json`
/// the JSON (`{"session", "beside"}` with `compare`). With `html`, writes the
/// page there, only once both recordings have been read (a bad file leaves
/// any page already there as it was).
pub fn command(
    file: &Path,
    options: &Options,
    json: bool,
    html: Option<&Path>,
    compare: Option<&Path>,
) -> anyhow::Result<String> {
    let r = report_with(file, options)?;
    let other = compare.map(|c| report_with(c, options)).transpose()?;
    let mut out = if json {
        let value = match &other {
            Some(o) => serde_json::json!({ "session": r, "beside": o }),
            None => serde_json::to_value(&r)?,
        };
        serde_json::to_string_pretty(&value)? + "\n"
    } else {
        let mut s = table(&r);
        if let (Some(o), Some(c)) = (&other, compare) {
            s.push_str(&format!("\nbeside it, {}:\n\n", c.display()));
            s.push_str(&table(o));
        }
        s
    };
    if let Some(page) = html {
        let beside = compare.map(|c| c.display().to_string());
        html::write(
            page,
            &r,
            &file.display().to_string(),
            other.as_ref().zip(beside.as_deref()),
        )?;
        if !json {
            out.push_str(&format!("\npage written: {}\n", page.display()));
        }
    }
    Ok(out)
}

/// The trajectories of a recording, per instrument (the accepted poses).
pub fn trajectories(path: &Path) -> anyhow::Result<Vec<(String, Trajectory)>> {
    let (entries, _) = recording::read(path)?;
    let mut out: BTreeMap<String, Vec<Waypoint>> = BTreeMap::new();
    for e in entries {
        if let Some(pb::recording_entry::Entry::Pose(p)) = e.entry {
            if let (Some(pose), name) = (p.pose, p.instrument) {
                let pos = pose.position_m.unwrap_or_default();
                let q = pose.orientation.unwrap_or_default();
                out.entry(name).or_default().push(Waypoint {
                    t_s: pose.t_s,
                    x_m: pos.x,
                    y_m: pos.y,
                    z_m: pos.z,
                    qw: q.w,
                    qx: q.x,
                    qy: q.y,
                    qz: q.z,
                });
            }
        }
    }
    Ok(out
        .into_iter()
        .map(|(n, points)| (n, Trajectory { points }))
        .collect())
}

/// The report as a table.
pub fn table(r: &Report) -> String {
    let mut s = format!(
        "recording of scene {}: {:.3} s, {} frames ({} failed){}\n\n",
        r.scene,
        r.duration_s,
        r.frames,
        r.failed_frames,
        if r.truncated {
            ", last entry truncated"
        } else {
            ""
        }
    );
    if r.lost.total() > 0 || r.lost.gaps > 0 {
        s.insert_str(
            s.len() - 1,
            &format!(
                "entries lost (the recorder's queue to the disk was full): poses {}, \
                 force samples {}, frames {}, in {} gap{}\n",
                r.lost.poses,
                r.lost.forces,
                r.lost.frames,
                r.lost.gaps,
                if r.lost.gaps == 1 { "" } else { "s" }
            ),
        );
    }
    s.push_str(&format!(
        "{:<10} {:>8} {:>10} {:>11} {:>14} {:>17} {:>13} {:>16}\n",
        "instrument",
        "samples",
        "duration s",
        "peak |F| N",
        "mean |F| N (c)",
        format!("t > {:.2} N (s)", r.threshold_n),
        "path length m",
        "time in contact s"
    ));
    for i in &r.instruments {
        s.push_str(&format!(
            "{:<10} {:>8} {:>10.3} {:>11.4} {:>14.4} {:>17.3} {:>13.4} {:>16.3}\n",
            i.instrument,
            i.samples,
            i.duration_s,
            i.peak_force_n,
            i.mean_force_in_contact_n,
            i.time_above_threshold_s,
            i.path_length_m,
            i.time_in_contact_s
        ));
    }
    if let Some(m) = &r.motion {
        s.push_str(&format!(
            "\nframe {} (largest surface displacement {:.2} mm):\n",
            m.frame,
            m.max_displacement_m * 1e3
        ));
        s.push_str(&m.lines());
    }
    if let Some(t) = &r.ties {
        s.push('\n');
        s.push_str(&t.lines());
    }
    s.push_str(&assessment_lines(&r.assessment));
    s
}

/// The assessment as text: the scores, then the events.
pub fn assessment_lines(a: &assess::Assessment) -> String {
    let mut s = format!(
        "\nassessment (thresholds: {}): {}\n",
        if a.thresholds_from_scene {
            "the scene's"
        } else {
            "the defaults; the recording carries none"
        },
        a.grade.map_or("nothing scored", |g| g.name())
    );
    s.push_str(&format!(
        "{:<40} {:<10} {:>26} {:>6} {:>26} {:>26}\n",
        "measure", "instrument", "value", "grade", "warns at", "fails at"
    ));
    for m in &a.scores {
        s.push_str(&format!(
            "{:<40} {:<10} {:>26} {:>6} {:>26} {:>26}\n",
            m.measure,
            m.instrument.as_deref().unwrap_or("-"),
            m.shown(m.value),
            m.grade.name(),
            m.shown(m.levels.warn),
            m.shown(m.levels.fail),
        ));
    }
    if a.events.is_empty() {
        s.push_str("events: none\n");
    } else {
        s.push_str("events:\n");
        for e in &a.events {
            s.push_str(&format!(
                "  t = {:>8.3} s  {:<10} {}{}\n",
                e.t_s,
                e.instrument,
                e.what,
                if e.injury { " (an injury)" } else { "" }
            ));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use fissure_proto::recording::RecordingGap;
    use pb::recording_entry::Entry;
    use prost::Message;

    fn put(file: &mut Vec<u8>, e: Entry) {
        file.extend(pb::RecordingEntry { entry: Some(e) }.encode_length_delimited_to_vec());
    }

    /// A recording of `left` at 1 kHz: samples `seqs` (pose and force each,
    /// 1 mm apart along x, 0.2 N), a frame, and a gap after each sample
    /// listed in `gaps`.
    fn write(path: &Path, seqs: &[u64], gaps: &[(u64, RecordingGap)]) {
        let mut file = Vec::new();
        put(
            &mut file,
            Entry::Header(pb::RecordingHeader {
                version: 1,
                scene: Some(pb::SceneDescription {
                    name: "cube".into(),
                    ..Default::default()
                }),
                started_unix_s: 0.0,
                surface: None,
            }),
        );
        for &k in seqs {
            let t_s = k as f64 * 1e-3;
            put(
                &mut file,
                Entry::Pose(pb::RecordedPose {
                    instrument: "left".into(),
                    pose: Some(pb::PoseSample {
                        t_s,
                        sequence: k,
                        position_m: Some(pb::Vec3 {
                            x: k as f64 * 1e-3,
                            y: 0.0,
                            z: 0.0,
                        }),
                        ..Default::default()
                    }),
                }),
            );
            put(
                &mut file,
                Entry::Force(pb::RecordedForce {
                    instrument: "left".into(),
                    sample: Some(pb::ForceSample {
                        t_s,
                        sequence: k,
                        force_n: Some(pb::Vec3 {
                            x: 0.0,
                            y: 0.0,
                            z: 0.2,
                        }),
                        contact_count: 1,
                        ..Default::default()
                    }),
                }),
            );
            put(
                &mut file,
                Entry::Frame(pb::DeformationFrame {
                    frame: k,
                    ..Default::default()
                }),
            );
            for (_, g) in gaps.iter().filter(|(after, _)| *after == k) {
                put(&mut file, Entry::Gap(*g));
            }
        }
        std::fs::write(path, file).unwrap();
    }

    #[test]
    fn released_ties_are_counted_and_listed_and_a_torn_vessel_is_an_injury() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ties.fsrec");
        let mut file = Vec::new();
        let frame = |k: u64, intact: (u32, u32), events: Vec<pb::TieEvent>| {
            Entry::Frame(pb::DeformationFrame {
                frame: k,
                ties: Some(pb::TieSummary {
                    trabeculae_intact: intact.0,
                    vessels_intact: intact.1,
                    events,
                    released: Vec::new(),
                }),
                ..Default::default()
            })
        };
        let event = |t: f64, tie: u32, kind: pb::TieKind, cause: pb::TieCause| pb::TieEvent {
            sim_time_s: t,
            tie,
            kind: kind as i32,
            cause: cause as i32,
            instrument: "blade".into(),
            position_m: Some(pb::Vec3 {
                x: -0.06,
                y: 0.01,
                z: 0.0,
            }),
            strain: 0.25,
        };
        put(
            &mut file,
            Entry::Header(pb::RecordingHeader {
                version: 1,
                scene: Some(pb::SceneDescription {
                    name: "sylvian-arachnoid".into(),
                    ..Default::default()
                }),
                started_unix_s: 0.0,
                surface: None,
            }),
        );
        put(&mut file, frame(0, (10, 2), vec![]));
        put(
            &mut file,
            frame(
                1,
                (8, 2),
                vec![
                    event(0.02, 3, pb::TieKind::Trabecula, pb::TieCause::Cut),
                    event(0.02, 4, pb::TieKind::Trabecula, pb::TieCause::Torn),
                ],
            ),
        );
        put(
            &mut file,
            frame(
                2,
                (8, 1),
                vec![event(0.04, 10, pb::TieKind::Vessel, pb::TieCause::Torn)],
            ),
        );
        std::fs::write(&path, file).unwrap();
        let r = report(&path, 1.0).unwrap();
        let t = r.ties.as_ref().expect("ties reported");
        assert_eq!((t.first, t.last, t.events.len()), ((10, 2), (8, 1), 3));
        let text = table(&r);
        assert!(
            text.contains("ties: trabeculae 10 -> 8 intact (1 cut, 1 torn); vessels 2 -> 1 intact (0 cut, 1 torn: an injury)"),
            "{text}"
        );
        assert!(text.contains("vessel       10 torn by blade"), "{text}");
    }

    #[test]
    fn a_recording_with_gaps_reports_the_entries_lost() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gaps.fsrec");
        let stall = RecordingGap {
            poses: 3,
            forces: 3,
            frames: 3,
        };
        let end = RecordingGap {
            poses: 2,
            forces: 1,
            frames: 0,
        };
        write(&path, &[1, 5, 6], &[(1, stall), (6, end)]);
        let r = report(&path, 0.1).unwrap();
        assert_eq!(
            r.lost,
            LostEntries {
                poses: 5,
                forces: 4,
                frames: 3,
                gaps: 2
            }
        );
        assert_eq!(r.lost.total(), 12);
        // The figures cover what was recorded.
        assert_eq!((r.frames, r.instruments.len()), (3, 1));
        let left = &r.instruments[0];
        assert_eq!(left.samples, 3);
        assert!((left.duration_s - 5e-3).abs() < 1e-12);
        assert!((left.path_length_m - 5e-3).abs() < 1e-12);

        let t = table(&r);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(
            lines[1],
            "entries lost (the recorder's queue to the disk was full): poses 5, \
             force samples 4, frames 3, in 2 gaps",
            "{t}"
        );
        assert_eq!(lines[2], "", "{t}");
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(
            json["lost"],
            serde_json::json!({"poses": 5, "forces": 4, "frames": 3, "gaps": 2})
        );
        // Replay takes the recorded poses only.
        let plans = trajectories(&path).unwrap();
        assert_eq!(plans.len(), 1);
        assert_eq!(plans[0].1.points.len(), 3);
    }

    #[test]
    fn a_complete_recording_reports_no_loss() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("complete.fsrec");
        write(&path, &[1, 2, 3], &[]);
        let r = report(&path, 0.1).unwrap();
        assert_eq!(r.lost, LostEntries::default());
        assert_eq!(r.instruments[0].samples, 3);
        let t = table(&r);
        assert!(!t.contains("lost"), "{t}");
        assert_eq!(t.lines().nth(1), Some(""), "{t}");
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(
            json["lost"],
            serde_json::json!({"poses": 0, "forces": 0, "frames": 0, "gaps": 0})
        );
    }

    /// A gap of zero counts (the recorder writes none, a file may hold one)
    /// is still a place: reported, with no loss.
    #[test]
    fn an_empty_gap_is_counted_as_a_place() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("empty-gap.fsrec");
        write(&path, &[1, 2], &[(1, RecordingGap::default())]);
        let r = report(&path, 0.1).unwrap();
        assert_eq!(
            r.lost,
            LostEntries {
                gaps: 1,
                ..Default::default()
            }
        );
        assert!(table(&r).contains("poses 0, force samples 0, frames 0, in 1 gap\n"));
    }
}
