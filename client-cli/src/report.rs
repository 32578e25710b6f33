//! `fissure report`: a summary of a session recording, and the trajectories it
//! holds (for `fissure replay --recording`).

use crate::trajectory::{Trajectory, Waypoint};
use fissure_proto::v1 as pb;
use fissure_server::sim::recording;
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
    /// Per instrument.
    pub instruments: Vec<InstrumentReport>,
}

fn norm(v: &Option<pb::Vec3>) -> f64 {
    v.as_ref()
        .map_or(0.0, |v| (v.x * v.x + v.y * v.y + v.z * v.z).sqrt())
}

/// Reads a recording and summarises it; `threshold_n` is the safe-force threshold.
pub fn report(path: &Path, threshold_n: f64) -> anyhow::Result<Report> {
    let (entries, truncated) = recording::read(path)?;
    let mut scene = String::new();
    let mut frames = 0;
    let mut failed_frames = 0;
    let mut forces: BTreeMap<String, Vec<pb::ForceSample>> = BTreeMap::new();
    let mut poses: BTreeMap<String, Vec<pb::PoseSample>> = BTreeMap::new();
    for e in entries {
        match e.entry {
            Some(pb::recording_entry::Entry::Header(h)) => {
                scene = h.scene.map(|s| s.name).unwrap_or_default()
            }
            Some(pb::recording_entry::Entry::Pose(p)) => {
                poses.entry(p.instrument).or_default().extend(p.pose);
            }
            Some(pb::recording_entry::Entry::Force(f)) => {
                forces.entry(f.instrument).or_default().extend(f.sample);
            }
            Some(pb::recording_entry::Entry::Frame(f)) => {
                frames += 1;
                if !f.solver_error.is_empty() {
                    failed_frames += 1;
                }
            }
            None => {}
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
    }
    Ok(Report {
        scene,
        duration_s: if t_max >= t_min { t_max - t_min } else { 0.0 },
        frames,
        failed_frames,
        threshold_n,
        truncated,
        instruments,
    })
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
    s
}
