//! `fissure bench haptic`: the force loop's samples against a full solve at
//! every sample, on every scene with bundled trajectories, in one run
//! (DESIGN.md sections 3b and 4).
//!
//! # Runs
//! A scene's `k`-th run gives each of its instruments its `k`-th bundled
//! trajectory ([`plan`]); an instrument without one stays at home. So
//! `sylvian` runs both spatulas at once, `v-valley` each of its two
//! trajectories, `cube` the two presses together and then the left plate's
//! press/hold/retract alone.
//!
//! A run drives the product's stepped runner ([`SteppedRunner`]: the
//! server's stepped mode, `fissure study`) at the trajectories' sample
//! times (1 kHz): at each time it answers every instrument posed then, with
//! a deformation step every `loops.deformation_interval_s`. Beside it a
//! second [`StepEngine`] of the same scene (compliance columns computed as
//! needed) takes a step at every sample time with the same poses (an
//! instrument not posed at that time at its latest pose, or at home before
//! its first and after its last), chained from its own previous snapshot:
//! the full solve of the contact problem at that sample's poses, whose force
//! on instrument `i` is `F_full`. For linear elasticity the force loop
//! solves the same problem on the same compliance, so `F_sample = F_full`
//! to the contact solver's tolerance. (The full solve finds its contact
//! rows on its own previous shape, 1 ms old; `hold_variation_full_rel`
//! shows whether it settles at a held pose.) In scenes with ties the full
//! solve takes the ties the runner's force loops have at that sample (cut
//! by a blade in a sample, torn at the runner's steps) and tears none
//! itself ([`StepEngine::mirror_ties`]): a sample is checked with its own
//! ties, as the law says.
//!
//! `--strategy` runs every scene with another strategy: with
//! `corotational` or `neo-hookean` the force loop solves on the tangent
//! compliance of the last step, and the measures give the error of that
//! linearization against a full nonlinear solve at every sample.
//!
//! # Measures (per run; N, s)
//! `P` is the run's peak `|F_full|` over all instruments and samples. A
//! sample is *in contact* when `F_sample` or `F_full` is non-zero.
//! * `max_error_rel`: `max |F_sample - F_full| / P` over every instrument
//!   and sample (where, and both forces there: `max_error_*`);
//!   `rms_error_rel`: the root mean square of `|F_sample - F_full|` over
//!   the samples in contact, over `P`.
//! * `ripple_ratio`: over pairs of consecutive samples of one instrument
//!   with either in contact, the mean `|F_k - F_{k-1}|` of the pairs whose
//!   answers came from different deformation frames over that of the pairs
//!   inside one frame (1 when a frame change is invisible);
//!   `ripple_ratio_full`, the same pairs of `F_full` (the motion's own
//!   share).
//! * `ripple_amplitude_n`: the amplitude of `|F_sample|` at the deformation
//!   rate `1 / dt`, `2 |sum_k w_k |F_k| exp(-2 pi i t_k / dt)| / sum_k w_k`
//!   with a Hann window `w` over the instrument's samples (so that the
//!   slow force of the motion does not leak into the frame rate); the
//!   largest over instruments. `ripple_amplitude_full_n`: the same of
//!   `|F_full|`.
//! * `onset_error_rel`: contact *begins* at a sample in contact whose
//!   predecessor (of that instrument) was not, or at an instrument's first
//!   sample when it is in contact. Over the samples of the
//!   `--onset-window-ms` (20 ms) from there, `max |F_sample - F_full|`
//!   over the window's peak `|F_full|` (its peak `|F_sample|` if the full
//!   solve has no force there: an error of 1); the largest over onsets.
//! * `hysteresis_rel` (runs on the `cube`, whose top face is flat, that
//!   drive one plate: with another moving, the force at a depth depends on
//!   its depth too; null elsewhere): the depth `d` of a plate is how far
//!   its lowest corner lies below the block's rest top surface. The press
//!   branch is an instrument's samples up to its first at the deepest
//!   depth, the retract branch those from its last there. At every press
//!   sample deeper than `--hysteresis-min-depth-m`, `|F_out(d) - F_in(d)|`
//!   with `F_out` interpolated linearly in depth between the retract
//!   samples around `d`; the largest over `P`. Frictionless contact on
//!   linear elasticity has one force per depth: 0 up to the solver's
//!   tolerance. The default depth 0 takes every depth in contact: the
//!   difference is over `P`, so shallow depths cannot inflate it (and the
//!   cube's mesh spacing, 5 mm, is deeper than its 3 mm press).
//!   `hysteresis_full_rel`: the same of `F_full`.
//! * `min_normal_force_n`: the least normal force of one face of a plate.
//!   At a sample where the full solve's rows of the instrument push on one
//!   of its two large faces and not the other (rim rows lie in the plate's
//!   plane and add nothing along its normal), `F_sample . (-n)` with `n`
//!   that face's outward normal from the pose (at mid-length for a curved
//!   plate): the sum of the face's normal reactions, `>= 0` for a contact
//!   that only pushes. Samples with both faces pushing (a plate wedged in
//!   the V groove) leave the net force's share of each face unknown and are
//!   not counted (`normal_force_samples` says how many were).
//! * `hold_variation_rel`: a *hold* is a stretch of samples over which no
//!   instrument's pose changes lasting at least `--hold-window-ms`
//!   (100 ms); over its last window, the standard deviation of
//!   `|F_sample|` over its mean, for every instrument whose `|F_full|` is
//!   non-zero there (a sample force of zero throughout while the full
//!   solve pushes, a contact the force loop lost, counts as 1); the largest
//!   over holds and instruments.
//!   `hold_variation_full_rel`: the same of `|F_full|` (a full solve that
//!   does not settle).
//! * `model_age_max_ms` (sample time minus its frame's), `sample_us_p50`,
//!   `sample_us_p99` (the force loop's compute time per sample and
//!   instrument), `step_ms_p50` (the runner's deformation steps) and
//!   `full_step_ms_p50` (the full solve per sample), for context;
//!   `flagged_samples` (a penalty answered a vertex without compliance, or
//!   the sample's contact problem failed), failed steps of both.
//!
//! The targets ([`TARGETS`]) are printed beside the figures with a
//! pass/fail column; a missed target is a finding, not an error (the
//! command exits 0 unless something fails to run).

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::client::trajectory::{BUNDLED, Trajectory, Waypoint};
use anyhow::{Context, bail};
use fissure_engine::collide::FaceId;
use fissure_engine::fem::RowKind;
use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::scene::{EMBEDDED, ModelSpec, Scene};
use fissure_engine::sim::core::engine::{Model, StepEngine};
use fissure_engine::sim::core::rows::face_of_key;
use fissure_engine::sim::core::snapshot::Snapshot;
use fissure_engine::sim::core::stepped::{Answer, StepDone, SteppedRunner, home_pose};
use fissure_engine::sim::flags;
use fissure_engine::sim::runtime::stats::percentile;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

/// Options of `fissure bench haptic`.
#[derive(Debug, Clone, clap::Args)]
pub struct HapticArgs {
    /// Scenes to run (repeatable or comma-separated): embedded scenes with
    /// bundled trajectories. All of them by default. Or one scene file (a
    /// `.toml`, such as `fissure scene from-image` writes) with its
    /// trajectory files in --trajectory.
    #[arg(long, value_delimiter = ',')]
    pub scene: Vec<String>,
    /// Only the runs that use one of these bundled trajectories
    /// (repeatable or comma-separated; a run keeps its other instruments'
    /// trajectories). All runs by default. With a scene file: its
    /// trajectories, as `fissure demo --trajectory` takes them (one file of
    /// several instruments, or NAME=FILE each).
    #[arg(long, value_delimiter = ',')]
    pub trajectory: Vec<String>,
    /// Cut every run after this long, s (whole trajectories by default).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Run every scene with this solver strategy (direct, compliance,
    /// corotational, neo-hookean) instead of its own: the nonlinear ones
    /// give the force loop the tangent compliance of their last step. A
    /// scene the strategy cannot run (`corotational` with the nodal-pressure
    /// element) is refused, naming why.
    #[arg(long)]
    pub strategy: Option<String>,
    /// Window after contact begins of the onset error, ms.
    #[arg(long, default_value_t = 20.0)]
    pub onset_window_ms: f64,
    /// Least length of a hold, and the window at its end whose force
    /// variation is measured, ms.
    #[arg(long, default_value_t = 100.0)]
    pub hold_window_ms: f64,
    /// Depths (below the cube's rest top surface) the hysteresis is
    /// measured deeper than, m.
    #[arg(long, default_value_t = 0.0)]
    pub hysteresis_min_depth_m: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// No progress on stderr.
    #[arg(long)]
    pub quiet: bool,
}

impl Default for HapticArgs {
    fn default() -> Self {
        Self {
            scene: Vec::new(),
            trajectory: Vec::new(),
            duration_s: None,
            strategy: None,
            onset_window_ms: 20.0,
            hold_window_ms: 100.0,
            hysteresis_min_depth_m: 0.0,
            json: false,
            quiet: false,
        }
    }
}

/// A target of a measure: its JSON key, `<=` or `>=`, the bound.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// The measure's key.
    pub key: &'static str,
    /// Whether the measure must be at most (`true`) or at least the bound.
    pub at_most: bool,
    /// The bound.
    pub bound: f64,
}

/// The contact design's targets for this benchmark.
pub const TARGETS: &[Target] = &[
    Target {
        key: "max_error_rel",
        at_most: true,
        bound: 0.01,
    },
    Target {
        key: "ripple_ratio",
        at_most: true,
        bound: 1.5,
    },
    Target {
        key: "onset_error_rel",
        at_most: true,
        bound: 0.05,
    },
    Target {
        key: "hysteresis_rel",
        at_most: true,
        bound: 0.01,
    },
    Target {
        key: "min_normal_force_n",
        at_most: false,
        bound: -1e-9,
    },
    Target {
        key: "hold_variation_rel",
        at_most: true,
        bound: 0.01,
    },
];

/// A run to measure: the scene (embedded name or file), `(instrument,
/// trajectory name)` per driven instrument, and for a scene file the
/// trajectories read from its files.
type PreparedRun = (
    String,
    Vec<(String, String)>,
    Option<crate::client::trajectory::TrajectorySet>,
);

/// One run: a scene and the bundled trajectory of each instrument it
/// drives, `(instrument, trajectory)`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunPlan {
    /// The scene (embedded name).
    pub scene: String,
    /// `(instrument, bundled trajectory)`, in the scene's instrument order.
    pub tracks: Vec<(String, String)>,
}

/// The embedded scenes with bundled trajectories, in the embedding order.
pub fn bench_scenes() -> Vec<&'static str> {
    EMBEDDED
        .iter()
        .map(|(n, _)| *n)
        .filter(|n| BUNDLED.iter().any(|b| b.1 == *n))
        .collect()
}

/// The runs of `scenes` (all scenes with bundled trajectories when empty),
/// restricted to those using one of `only` when it is not empty (module
/// documentation).
pub fn plan(scenes: &[String], only: &[String]) -> anyhow::Result<Vec<RunPlan>> {
    let known = bench_scenes();
    for s in scenes {
        if !known.contains(&s.as_str()) {
            bail!(
                "--scene {s:?}: not an embedded scene with bundled trajectories ({})",
                known.join(", ")
            );
        }
    }
    for t in only {
        if !BUNDLED.iter().any(|b| b.0 == t) {
            bail!(
                "--trajectory {t:?}: not a bundled trajectory ({})",
                BUNDLED.iter().map(|b| b.0).collect::<Vec<_>>().join(", ")
            );
        }
    }
    let mut runs = Vec::new();
    for name in known {
        if !scenes.is_empty() && !scenes.iter().any(|s| s == name) {
            continue;
        }
        let (scene, _) = Scene::load(name).with_context(|| format!("loading scene {name:?}"))?;
        let per_instrument: Vec<(String, Vec<&str>)> = scene
            .instruments
            .iter()
            .map(|spec| {
                let names = BUNDLED
                    .iter()
                    .filter(|b| b.1 == name && b.2 == spec.name)
                    .map(|b| b.0)
                    .collect();
                (spec.name.clone(), names)
            })
            .collect();
        let count = per_instrument.iter().map(|p| p.1.len()).max().unwrap_or(0);
        for k in 0..count {
            let tracks: Vec<(String, String)> = per_instrument
                .iter()
                .filter_map(|(inst, names)| names.get(k).map(|t| (inst.clone(), t.to_string())))
                .collect();
            if only.is_empty() || tracks.iter().any(|(_, t)| only.contains(t)) {
                runs.push(RunPlan {
                    scene: name.to_owned(),
                    tracks,
                });
            }
        }
    }
    if runs.is_empty() {
        bail!("no run uses the given --scene and --trajectory");
    }
    Ok(runs)
}

/// What one run recorded of one instrument, one entry per answered sample.
#[derive(Debug, Clone, Default)]
pub struct InstrumentSeries {
    /// The instrument's index in the scene.
    pub instrument: usize,
    /// Its name.
    pub name: String,
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// The force loop's force, N.
    pub sample_n: Vec<Vector3<f64>>,
    /// The full solve's force at the same poses, N.
    pub full_n: Vec<Vector3<f64>>,
    /// The deformation frame each sample was answered from.
    pub frame: Vec<u64>,
    /// The sample's flags ([`flags`]).
    pub flags: Vec<u32>,
    /// `F_sample . (-n)` of the one large face the full solve pushes, N
    /// (module documentation); `None` where it pushes neither or both.
    pub normal_n: Vec<Option<f64>>,
    /// Depth of the plate's lowest corner below the highest rest surface
    /// point, m (negative above it).
    pub depth_m: Vec<f64>,
}

/// What one run recorded.
#[derive(Debug, Clone, Default)]
pub struct Measurement {
    /// The scene.
    pub scene: String,
    /// The solver strategy it ran with.
    pub strategy: String,
    /// The deformation interval, s.
    pub dt_s: f64,
    /// Whether the scene's model is the cube (a flat top: depths mean
    /// something).
    pub flat_top: bool,
    /// Sample times, s.
    pub times: Vec<f64>,
    /// Per time: no instrument's pose changed since the previous time
    /// (false at the first).
    pub still: Vec<bool>,
    /// The driven instruments.
    pub series: Vec<InstrumentSeries>,
    /// Every answer's model age, s.
    pub model_age_s: Vec<f64>,
    /// Every answer's compute time, us.
    pub compute_us: Vec<f64>,
    /// The runner's deformation steps, us.
    pub step_us: Vec<f64>,
    /// The full solve's steps, us.
    pub full_step_us: Vec<f64>,
    /// Failed deformation steps of the runner.
    pub failed_steps: usize,
    /// Failed steps of the full solve.
    pub failed_full_steps: usize,
}

/// The pose of a waypoint.
pub fn pose_of(p: &Waypoint) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p.x_m, p.y_m, p.z_m),
        UnitQuaternion::new_normalize(Quaternion::new(p.qw, p.qx, p.qy, p.qz)),
    )
}

/// The lowest z of the plate of instrument `i` at `pose` (its eight
/// corners: both ends, both edges, both faces), m.
fn lowest_corner_z(model: &Model, i: usize, pose: &Isometry3<f64>) -> f64 {
    let plate = &model.instruments[i].plate;
    let mut low = f64::INFINITY;
    for s in [0.0, plate.length] {
        let (m, n, _) = plate.frame_at(s, 0.0);
        let half_w = 0.5 * plate.width_at(s);
        for y in [-half_w, half_w] {
            for t in [-0.5 * plate.thickness, 0.5 * plate.thickness] {
                let corner = m + Vector3::y() * y + n * t;
                low = low.min((pose * corner).z);
            }
        }
    }
    low
}

/// `F . (-n)` of the one large face of instrument `i` the full solve's
/// snapshot pushes (module documentation), `None` if it pushes neither or
/// both.
fn one_face_normal(
    model: &Model,
    full: &Snapshot,
    i: usize,
    pose: &Isometry3<f64>,
    force: &Vector3<f64>,
) -> Option<f64> {
    let fm = &full.force_model;
    let (mut a, mut b) = (0.0, 0.0);
    for (r, &l) in fm.step_rows.iter().zip(&fm.step_lambda) {
        if r.owner as usize != i || r.row.kind != RowKind::Unilateral || l <= 0.0 {
            continue;
        }
        let face = face_of_key(r.key) as usize;
        if face == FaceId::A.index() {
            a += l;
        } else if face == FaceId::B.index() {
            b += l;
        }
    }
    let plate = &model.instruments[i].plate;
    let n_a = pose.rotation * plate.frame_at(0.5 * plate.length, 0.0).1;
    // (+ 0.0: a zero force reads 0, not -0.)
    match (a > 0.0, b > 0.0) {
        (true, false) => Some(-force.dot(&n_a) + 0.0),
        (false, true) => Some(force.dot(&n_a) + 0.0),
        _ => None,
    }
}

/// Runs `tracks` (`(instrument index, trajectory)`) on `scene` over
/// `model`: the stepped runner and the full solve at every sample time
/// (module documentation), cut after `until_s` from the first time if
/// given. `progress(done, total)` is called after every sample time.
pub fn measure(
    scene: &Scene,
    model: &Arc<Model>,
    tracks: &[(usize, Trajectory)],
    until_s: Option<f64>,
    progress: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<Measurement> {
    let n = scene.instruments.len();
    for (j, (i, _)) in tracks.iter().enumerate() {
        if *i >= n {
            bail!("instrument index {i} out of range (the scene has {n})");
        }
        if tracks[..j].iter().any(|(k, _)| k == i) {
            bail!(
                "instrument {:?} has two trajectories",
                scene.instruments[*i].name
            );
        }
    }
    let mut times: Vec<f64> = tracks
        .iter()
        .flat_map(|(_, t)| t.points.iter().map(|p| p.t_s))
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    if let (Some(u), Some(&t0)) = (until_s, times.first()) {
        times.retain(|&t| t - t0 <= u);
    }
    if times.is_empty() {
        bail!("no sample to run");
    }
    let mut runner = SteppedRunner::for_scene(scene, model.clone(), ColumnPolicy::Compute)
        .context("building the stepped runner")?;
    let mut full = StepEngine::new(scene, model.clone(), ColumnPolicy::Compute, None, None)
        .context("building the full solve")?;
    let mut full_snap = full.rest(times[0]);
    let homes: Vec<Isometry3<f64>> = (0..n).map(|i| home_pose(scene, i)).collect();
    let z_top = model
        .rest_surface
        .iter()
        .map(|p| p.z)
        .fold(f64::NEG_INFINITY, f64::max);
    let mut m = Measurement {
        scene: scene.name.clone(),
        strategy: scene.solver.strategy.name().into(),
        dt_s: scene.loops.deformation_interval_s,
        flat_top: matches!(scene.model, ModelSpec::Cube { .. }),
        times: Vec::with_capacity(times.len()),
        still: Vec::with_capacity(times.len()),
        series: tracks
            .iter()
            .map(|(i, _)| InstrumentSeries {
                instrument: *i,
                name: scene.instruments[*i].name.clone(),
                ..InstrumentSeries::default()
            })
            .collect(),
        ..Measurement::default()
    };
    let mut series_of = vec![usize::MAX; n];
    for (j, (i, _)) in tracks.iter().enumerate() {
        series_of[*i] = j;
    }
    let mut current = homes.clone();
    let mut cursor = vec![0usize; tracks.len()];
    let mut ended = vec![false; tracks.len()];
    let mut posed: Vec<(usize, Isometry3<f64>)> = Vec::with_capacity(n);
    let mut answers: Vec<Answer> = Vec::with_capacity(n);
    let (mut step_us, mut failed_steps) = (Vec::new(), 0usize);
    let total = times.len();
    for (k, &t) in times.iter().enumerate() {
        let before = current.clone();
        posed.clear();
        for (j, (i, traj)) in tracks.iter().enumerate() {
            let pts = &traj.points;
            let mut hit = None;
            while cursor[j] < pts.len() && pts[cursor[j]].t_s <= t {
                hit = Some(pose_of(&pts[cursor[j]]));
                cursor[j] += 1;
            }
            match hit {
                Some(pose) => {
                    posed.push((*i, pose));
                    current[*i] = pose;
                }
                None if cursor[j] >= pts.len() && !ended[j] => {
                    runner.end(*i);
                    ended[j] = true;
                    current[*i] = homes[*i];
                }
                None => {}
            }
        }
        m.times.push(t);
        m.still.push(k > 0 && current == before);
        answers.clear();
        runner.tick(
            t,
            &posed,
            &mut |d: &StepDone| {
                step_us.push(d.step_us);
                if d.report.is_none() && d.snapshot.solver_error.is_some() {
                    failed_steps += 1;
                }
            },
            &mut answers,
        );
        // The ties as the runner's force loops have them (cut by a blade in
        // a sample, torn at the runner's steps): the full solve checks the
        // samples with those ties, not with ties it would tear itself.
        if let Some(ties) = &runner.snapshot().force_model.ties {
            full.mirror_ties(ties);
        }
        let started = Instant::now();
        let (snap, report) = full.step(&full_snap, t, &current, vec![None; n]);
        m.full_step_us.push(started.elapsed().as_secs_f64() * 1e6);
        if report.is_none() {
            m.failed_full_steps += 1;
        }
        full_snap = snap;
        for a in &answers {
            let i = a.instrument;
            let pose = current[i];
            let f_full = full_snap.frame_summary.instruments[i].force_n;
            let s = &mut m.series[series_of[i]];
            s.t_s.push(t);
            s.sample_n.push(a.force.force_n);
            s.full_n.push(f_full);
            s.frame.push(a.frame);
            s.flags.push(a.force.flags);
            s.normal_n.push(one_face_normal(
                model,
                &full_snap,
                i,
                &pose,
                &a.force.force_n,
            ));
            s.depth_m.push(z_top - lowest_corner_z(model, i, &pose));
            m.model_age_s.push(a.model_age_s);
            m.compute_us.push(a.compute_us);
        }
        progress(k + 1, total);
    }
    m.step_us = step_us;
    m.failed_steps = failed_steps;
    Ok(m)
}

/// The measures of one run (module documentation). Forces N, times as
/// named; `None` (JSON null) where a measure has nothing to measure.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HapticRow {
    /// The scene.
    pub scene: String,
    /// The solver strategy.
    pub strategy: String,
    /// The bundled trajectories of the run.
    pub trajectories: Vec<String>,
    /// Answered samples (all instruments).
    pub samples: usize,
    /// Deformation steps of the runner.
    pub steps: usize,
    /// The run's peak |F_full|, N.
    pub peak_force_n: f64,
    /// rms |F_sample - F_full| over the samples in contact, over the peak.
    pub rms_error_rel: Option<f64>,
    /// max |F_sample - F_full| over the peak.
    pub max_error_rel: Option<f64>,
    /// The largest |F_sample - F_full|, N, with where it happened and both
    /// forces there.
    pub max_error_n: f64,
    pub max_error_at_s: Option<f64>,
    pub max_error_instrument: Option<String>,
    pub max_error_sample_n: Option<[f64; 3]>,
    pub max_error_full_n: Option<[f64; 3]>,
    /// Mean |dF| across frame changes over mean |dF| inside frames.
    pub ripple_ratio: Option<f64>,
    /// The same pairs of the full solve's forces.
    pub ripple_ratio_full: Option<f64>,
    /// Amplitude of |F_sample| at the deformation rate, N.
    pub ripple_amplitude_n: Option<f64>,
    /// Amplitude of |F_full| at the deformation rate, N.
    pub ripple_amplitude_full_n: Option<f64>,
    /// Error in the window after contact begins over the window's peak.
    pub onset_error_rel: Option<f64>,
    /// Onsets of contact measured.
    pub onsets: usize,
    /// max |F_out(d) - F_in(d)| over the peak (the cube).
    pub hysteresis_rel: Option<f64>,
    /// The same of the full solve's forces.
    pub hysteresis_full_rel: Option<f64>,
    /// Least F_sample . (-n) of a face the full solve pushes alone, N.
    pub min_normal_force_n: Option<f64>,
    /// Samples whose normal force was measured.
    pub normal_force_samples: usize,
    /// Largest std / mean of |F_sample| at the end of a hold.
    pub hold_variation_rel: Option<f64>,
    /// The same of |F_full|.
    pub hold_variation_full_rel: Option<f64>,
    /// Holds in contact measured.
    pub holds: usize,
    /// Largest model age of a sample, ms.
    pub model_age_max_ms: f64,
    /// Force-loop compute time per sample and instrument, us.
    pub sample_us_p50: f64,
    pub sample_us_p99: f64,
    /// The runner's deformation step, ms.
    pub step_ms_p50: f64,
    /// The full solve's step, ms.
    pub full_step_ms_p50: f64,
    /// Samples flagged COLUMNS_PENDING or CONTACT_UNSOLVED.
    pub flagged_samples: usize,
    /// Failed steps of the runner and of the full solve.
    pub failed_steps: usize,
    pub failed_full_steps: usize,
    /// Keys of the [`TARGETS`] the run misses.
    pub targets_failed: Vec<String>,
}

impl HapticRow {
    /// The value of a measure by its JSON key (the targets' measures).
    pub fn measure(&self, key: &str) -> Option<f64> {
        match key {
            "max_error_rel" => self.max_error_rel,
            "rms_error_rel" => self.rms_error_rel,
            "ripple_ratio" => self.ripple_ratio,
            "onset_error_rel" => self.onset_error_rel,
            "hysteresis_rel" => self.hysteresis_rel,
            "min_normal_force_n" => self.min_normal_force_n,
            "hold_variation_rel" => self.hold_variation_rel,
            _ => None,
        }
    }
}

/// Options of the summary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SummaryOptions {
    /// Onset window, s.
    pub onset_window_s: f64,
    /// Hold length and window, s.
    pub hold_window_s: f64,
    /// Hysteresis only deeper than this, m.
    pub hysteresis_min_depth_m: f64,
}

impl Default for SummaryOptions {
    fn default() -> Self {
        Self {
            onset_window_s: 0.020,
            hold_window_s: 0.100,
            hysteresis_min_depth_m: 0.0,
        }
    }
}

fn max_opt(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(x), Some(y)) => Some(x.max(y)),
        (x, None) => x,
        (None, y) => y,
    }
}

fn sorted(v: &[f64]) -> Vec<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s
}

/// The amplitude of `x(t)` at frequency `f_hz` through a Hann window
/// (module documentation).
pub fn amplitude_at(t: &[f64], x: &[f64], f_hz: f64) -> Option<f64> {
    let n = x.len();
    if n < 3 {
        return None;
    }
    let (mut re, mut im, mut wsum) = (0.0, 0.0, 0.0);
    for k in 0..n {
        let w = 0.5 * (1.0 - (2.0 * std::f64::consts::PI * k as f64 / (n - 1) as f64).cos());
        let phase = 2.0 * std::f64::consts::PI * f_hz * t[k];
        re += w * x[k] * phase.cos();
        im -= w * x[k] * phase.sin();
        wsum += w;
    }
    Some(2.0 * (re * re + im * im).sqrt() / wsum)
}

/// `max |F_out(d) - F_in(d)|` over the press samples deeper than `min_d`
/// (module documentation), N; `None` if no press sample is deeper than
/// `min_d` within the retract branch's depths.
pub fn hysteresis_n(depth: &[f64], force: &[f64], min_d: f64) -> Option<f64> {
    let deepest = depth.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !(deepest > min_d) {
        return None;
    }
    let first = depth.iter().position(|&d| d == deepest)?;
    let last = depth.iter().rposition(|&d| d == deepest)?;
    let out: Vec<(f64, f64)> = (last..depth.len()).map(|k| (depth[k], force[k])).collect();
    let mut worst: Option<f64> = None;
    for k in 0..=first {
        let d = depth[k];
        if !(d > min_d) {
            continue;
        }
        // The retract samples around d (depths fall along the branch).
        let Some(j) = out.windows(2).position(|w| w[0].0 >= d && d >= w[1].0) else {
            continue;
        };
        let ((d0, f0), (d1, f1)) = (out[j], out[j + 1]);
        let f_out = if d0 > d1 {
            f0 + (f1 - f0) * (d0 - d) / (d0 - d1)
        } else {
            0.5 * (f0 + f1)
        };
        worst = max_opt(worst, Some((f_out - force[k]).abs()));
    }
    worst
}

/// The coefficient of variation (population standard deviation over the
/// mean) of `x`; `None` when empty or the mean is not positive.
fn variation(x: &[f64]) -> Option<f64> {
    if x.is_empty() {
        return None;
    }
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    if !(mean > 0.0) {
        return None;
    }
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / x.len() as f64;
    Some(var.sqrt() / mean)
}

/// The measures of a run.
pub fn summarise(m: &Measurement, trajectories: &[String], o: &SummaryOptions) -> HapticRow {
    let mut row = HapticRow {
        scene: m.scene.clone(),
        strategy: m.strategy.clone(),
        trajectories: trajectories.to_vec(),
        samples: m.compute_us.len(),
        steps: m.step_us.len(),
        failed_steps: m.failed_steps,
        failed_full_steps: m.failed_full_steps,
        ..HapticRow::default()
    };
    let peak = m
        .series
        .iter()
        .flat_map(|s| s.full_n.iter().map(|f| f.norm()))
        .fold(0.0, f64::max);
    row.peak_force_n = peak;
    let rel = |v: f64| (peak > 0.0).then(|| v / peak);
    // Errors.
    let (mut sum2, mut in_contact) = (0.0, 0usize);
    for s in &m.series {
        for k in 0..s.t_s.len() {
            let (fs, ff) = (s.sample_n[k], s.full_n[k]);
            let e = (fs - ff).norm();
            if fs.norm() > 0.0 || ff.norm() > 0.0 {
                sum2 += e * e;
                in_contact += 1;
            }
            if e > row.max_error_n || row.max_error_at_s.is_none() {
                row.max_error_n = e;
                row.max_error_at_s = Some(s.t_s[k]);
                row.max_error_instrument = Some(s.name.clone());
                row.max_error_sample_n = Some([fs.x, fs.y, fs.z]);
                row.max_error_full_n = Some([ff.x, ff.y, ff.z]);
            }
            row.flagged_samples +=
                (s.flags[k] & (flags::COLUMNS_PENDING | flags::CONTACT_UNSOLVED) != 0) as usize;
        }
    }
    row.max_error_rel = rel(row.max_error_n);
    if in_contact > 0 {
        row.rms_error_rel = rel((sum2 / in_contact as f64).sqrt());
    }
    // Ripple.
    let mut jumps = [[0.0f64; 2]; 2]; // [sample, full][inside, across]
    let mut pairs = [0usize; 2];
    for s in &m.series {
        for k in 1..s.t_s.len() {
            let on = |j: usize| s.sample_n[j].norm() > 0.0 || s.full_n[j].norm() > 0.0;
            if !(on(k) || on(k - 1)) {
                continue;
            }
            let across = (s.frame[k] != s.frame[k - 1]) as usize;
            jumps[0][across] += (s.sample_n[k] - s.sample_n[k - 1]).norm();
            jumps[1][across] += (s.full_n[k] - s.full_n[k - 1]).norm();
            pairs[across] += 1;
        }
    }
    if pairs[0] > 0 && pairs[1] > 0 {
        let ratio = |j: &[f64; 2]| {
            let (inside, across) = (j[0] / pairs[0] as f64, j[1] / pairs[1] as f64);
            (inside > 0.0).then(|| across / inside)
        };
        row.ripple_ratio = ratio(&jumps[0]);
        row.ripple_ratio_full = ratio(&jumps[1]);
    }
    let f_frame = 1.0 / m.dt_s;
    for s in &m.series {
        let mag = |v: &[Vector3<f64>]| v.iter().map(|f| f.norm()).collect::<Vec<_>>();
        row.ripple_amplitude_n = max_opt(
            row.ripple_amplitude_n,
            amplitude_at(&s.t_s, &mag(&s.sample_n), f_frame),
        );
        row.ripple_amplitude_full_n = max_opt(
            row.ripple_amplitude_full_n,
            amplitude_at(&s.t_s, &mag(&s.full_n), f_frame),
        );
    }
    // Onsets.
    for s in &m.series {
        let on = |j: usize| s.sample_n[j].norm() > 0.0 || s.full_n[j].norm() > 0.0;
        for k in 0..s.t_s.len() {
            if !on(k) || (k > 0 && on(k - 1)) {
                continue;
            }
            let end = s.t_s[k] + o.onset_window_s;
            let (mut err, mut full_peak, mut sample_peak) = (0.0f64, 0.0f64, 0.0f64);
            for j in (k..s.t_s.len()).take_while(|&j| s.t_s[j] < end - 1e-12) {
                err = err.max((s.sample_n[j] - s.full_n[j]).norm());
                full_peak = full_peak.max(s.full_n[j].norm());
                sample_peak = sample_peak.max(s.sample_n[j].norm());
            }
            let denom = if full_peak > 0.0 {
                full_peak
            } else {
                sample_peak
            };
            row.onsets += 1;
            row.onset_error_rel = max_opt(row.onset_error_rel, Some(err / denom));
        }
    }
    // Hysteresis (the cube's flat top).
    if m.flat_top && m.series.len() == 1 && peak > 0.0 {
        for s in &m.series {
            let mag = |v: &[Vector3<f64>]| v.iter().map(|f| f.norm()).collect::<Vec<_>>();
            let d = o.hysteresis_min_depth_m;
            row.hysteresis_rel = max_opt(
                row.hysteresis_rel,
                hysteresis_n(&s.depth_m, &mag(&s.sample_n), d).map(|h| h / peak),
            );
            row.hysteresis_full_rel = max_opt(
                row.hysteresis_full_rel,
                hysteresis_n(&s.depth_m, &mag(&s.full_n), d).map(|h| h / peak),
            );
        }
    }
    // Normal force.
    for s in &m.series {
        for v in s.normal_n.iter().flatten() {
            row.normal_force_samples += 1;
            row.min_normal_force_n = Some(row.min_normal_force_n.map_or(*v, |m| m.min(*v)));
        }
    }
    // Holds.
    let mut a = 0;
    while a < m.times.len() {
        let mut b = a;
        while b + 1 < m.times.len() && m.still[b + 1] {
            b += 1;
        }
        let (t_a, t_b) = (m.times[a], m.times[b]);
        if t_b - t_a >= o.hold_window_s - 1e-9 {
            let from = t_b - o.hold_window_s - 1e-9;
            let mut counted = false;
            for s in &m.series {
                let window: Vec<usize> = (0..s.t_s.len())
                    .filter(|&k| s.t_s[k] >= from && s.t_s[k] <= t_b)
                    .collect();
                if window.is_empty() || window.iter().any(|&k| s.full_n[k].norm() == 0.0) {
                    continue;
                }
                let xs: Vec<f64> = window.iter().map(|&k| s.sample_n[k].norm()).collect();
                let xf: Vec<f64> = window.iter().map(|&k| s.full_n[k].norm()).collect();
                // A sample force of zero throughout is a variation of 1.
                row.hold_variation_rel =
                    max_opt(row.hold_variation_rel, Some(variation(&xs).unwrap_or(1.0)));
                row.hold_variation_full_rel = max_opt(row.hold_variation_full_rel, variation(&xf));
                counted = true;
            }
            row.holds += counted as usize;
        }
        a = b + 1;
    }
    // Cost.
    row.model_age_max_ms = m.model_age_s.iter().copied().fold(0.0, f64::max) * 1e3;
    let us = sorted(&m.compute_us);
    row.sample_us_p50 = percentile(&us, 0.50);
    row.sample_us_p99 = percentile(&us, 0.99);
    row.step_ms_p50 = percentile(&sorted(&m.step_us), 0.50) * 1e-3;
    row.full_step_ms_p50 = percentile(&sorted(&m.full_step_us), 0.50) * 1e-3;
    row.targets_failed = TARGETS
        .iter()
        .filter(|t| {
            row.measure(t.key).is_some_and(|v| {
                if t.at_most {
                    !(v <= t.bound)
                } else {
                    !(v >= t.bound)
                }
            })
        })
        .map(|t| t.key.to_owned())
        .collect();
    row
}

/// The report of `fissure bench haptic`.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HapticReport {
    /// One row per run.
    pub runs: Vec<HapticRow>,
    /// The targets: key, `<=` or `>=`, bound.
    pub targets: Vec<(String, String, f64)>,
}

fn progress_bar(label: &str, total: usize, hidden: bool) -> ProgressBar {
    if hidden {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} samples  eta {eta}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_message(label.to_owned());
    pb
}

/// Runs the benchmark.
pub fn run(args: &HapticArgs) -> anyhow::Result<HapticReport> {
    if let Some(d) = args.duration_s {
        if !(d > 0.0) {
            bail!("--duration-s must be positive, got {d}");
        }
    }
    if !(args.onset_window_ms > 0.0 && args.hold_window_ms > 0.0) {
        bail!("--onset-window-ms and --hold-window-ms must be positive");
    }
    if !(args.hysteresis_min_depth_m >= 0.0) {
        bail!("--hysteresis-min-depth-m must be at least 0");
    }
    // A scene file runs once with its trajectory files; embedded scenes
    // run their bundled trajectories.
    let file_scene = args
        .scene
        .iter()
        .find(|s| s.ends_with(".toml") || std::path::Path::new(s.as_str()).is_file());
    let runs: Vec<PreparedRun> = match file_scene {
        Some(file) => {
            if args.scene.len() != 1 {
                bail!("--scene {file:?}: a scene file runs alone (give no other --scene)");
            }
            if args.trajectory.is_empty() {
                bail!("--scene {file:?}: a scene file needs its --trajectory files");
            }
            let set = crate::client::trajectory::resolve(None, &args.trajectory)?;
            let names = set
                .iter()
                .map(|(i, _)| (i.clone(), format!("{i}: {}", args.trajectory.join(","))))
                .collect();
            vec![(file.clone(), names, Some(set))]
        }
        None => plan(&args.scene, &args.trajectory)?
            .into_iter()
            .map(|p| (p.scene, p.tracks, None))
            .collect(),
    };
    let opts = SummaryOptions {
        onset_window_s: args.onset_window_ms * 1e-3,
        hold_window_s: args.hold_window_ms * 1e-3,
        hysteresis_min_depth_m: args.hysteresis_min_depth_m,
    };
    let mut models: HashMap<String, Arc<Model>> = HashMap::new();
    let mut report = HapticReport {
        targets: TARGETS
            .iter()
            .map(|t| {
                let op = if t.at_most { "<=" } else { ">=" };
                (t.key.to_owned(), op.to_owned(), t.bound)
            })
            .collect(),
        ..HapticReport::default()
    };
    let strategy: Option<fissure_engine::fem::Strategy> = args
        .strategy
        .as_deref()
        .map(|s| s.parse().map_err(|e| anyhow::anyhow!("--strategy: {e}")))
        .transpose()?;
    for (r, (scene_name, plan_tracks, files)) in runs.iter().enumerate() {
        let (mut scene, _) =
            Scene::load(scene_name).with_context(|| format!("loading scene {scene_name:?}"))?;
        if let Some(s) = strategy {
            scene.solver.strategy = s;
            scene
                .validate(scene_name)
                .with_context(|| format!("scene {scene_name:?} with --strategy {}", s.name()))?;
        }
        let names: Vec<String> = plan_tracks.iter().map(|t| t.1.clone()).collect();
        let label = match files {
            Some(_) => format!("{} ({})", scene.name, args.trajectory.join(", ")),
            None => format!("{} ({})", scene_name, names.join(", ")),
        };
        if !args.quiet {
            eprintln!("bench haptic [{}/{}]: {label}", r + 1, runs.len());
        }
        let model = match models.get(scene_name) {
            Some(m) => m.clone(),
            None => {
                let m = Arc::new(
                    Model::build(&scene)
                        .with_context(|| format!("building the model of {scene_name:?}"))?,
                );
                models.insert(scene_name.clone(), m.clone());
                m
            }
        };
        let mut tracks = Vec::new();
        for (k, (instrument, name)) in plan_tracks.iter().enumerate() {
            let i = scene
                .instruments
                .iter()
                .position(|s| &s.name == instrument)
                .with_context(|| {
                    format!("scene {scene_name:?} has no instrument {instrument:?}")
                })?;
            let trajectory = match files {
                Some(set) => set[k].1.clone(),
                None => Trajectory::load(name)?,
            };
            tracks.push((i, trajectory));
        }
        let started = Instant::now();
        let pb = progress_bar(&label, 0, args.quiet);
        let m = measure(
            &scene,
            &model,
            &tracks,
            args.duration_s,
            &mut |done, total| {
                if done == 1 {
                    pb.set_length(total as u64);
                }
                pb.set_position(done as u64);
            },
        )
        .with_context(|| format!("running {label}"))?;
        pb.finish_and_clear();
        let row = summarise(&m, &names, &opts);
        if !args.quiet {
            eprintln!(
                "bench haptic [{}/{}]: {} samples in {:.1} s",
                r + 1,
                runs.len(),
                row.samples,
                started.elapsed().as_secs_f64()
            );
        }
        report.runs.push(row);
    }
    Ok(report)
}

fn cell(v: Option<f64>, scale: f64, prec: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{:.*}", prec, x * scale),
        Some(x) => format!("{x}"),
        None => "-".into(),
    }
}

fn sci(v: Option<f64>) -> String {
    match v {
        Some(x) => format!("{x:.2e}"),
        None => "-".into(),
    }
}

/// The report as tables: accuracy against the targets, then context and
/// cost.
pub fn table(r: &HapticReport) -> String {
    let mut s = String::from(
        "bench haptic — force samples of the stepped runner against a full solve at every sample\n\n",
    );
    let label = |row: &HapticRow| {
        format!(
            "{} ({}; {})",
            row.scene,
            row.trajectories.join(", "),
            row.strategy
        )
    };
    let w = r
        .runs
        .iter()
        .map(|row| label(row).len())
        .max()
        .unwrap_or(3)
        .max(3);
    s.push_str(&format!(
        "{:<w$} {:>8} {:>8} {:>7} {:>9} {:>8} {:>8} {:>10} {:>8}  {}\n",
        "run",
        "max err",
        "rms err",
        "ripple",
        "ripple",
        "onset",
        "hyst",
        "min F.n",
        "hold",
        "targets"
    ));
    s.push_str(&format!(
        "{:<w$} {:>8} {:>8} {:>7} {:>9} {:>8} {:>8} {:>10} {:>8}\n",
        "", "% peak", "% peak", "ratio", "mN@frame", "%", "% peak", "N", "%"
    ));
    s.push_str(&format!(
        "{:<w$} {:>8} {:>8} {:>7} {:>9} {:>8} {:>8} {:>10} {:>8}\n",
        "target", "<= 1", "", "<= 1.5", "", "<= 5", "<= 1", ">= -1e-9", "<= 1"
    ));
    for row in &r.runs {
        let verdict = if row.targets_failed.is_empty() {
            "pass".to_owned()
        } else {
            format!("FAIL {}", row.targets_failed.join(", "))
        };
        s.push_str(&format!(
            "{:<w$} {:>8} {:>8} {:>7} {:>9} {:>8} {:>8} {:>10} {:>8}  {verdict}\n",
            label(row),
            cell(row.max_error_rel, 100.0, 3),
            cell(row.rms_error_rel, 100.0, 3),
            cell(row.ripple_ratio, 1.0, 2),
            cell(row.ripple_amplitude_n, 1e3, 4),
            cell(row.onset_error_rel, 100.0, 2),
            cell(row.hysteresis_rel, 100.0, 3),
            sci(row.min_normal_force_n),
            cell(row.hold_variation_rel, 100.0, 3),
        ));
    }
    s.push_str(&format!(
        "\n{:<w$} {:>7} {:>8} {:>7} {:>9} {:>8} {:>7} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8}\n",
        "run (full solve; cost)",
        "samples",
        "peak N",
        "ripple",
        "ripple",
        "hold",
        "flagged",
        "failed",
        "age max",
        "sample",
        "sample",
        "step",
        "full",
    ));
    s.push_str(&format!(
        "{:<w$} {:>7} {:>8} {:>7} {:>9} {:>8} {:>7} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8}\n",
        "",
        "",
        "",
        "full",
        "full mN",
        "full %",
        "samples",
        "steps",
        "ms",
        "us p50",
        "us p99",
        "ms p50",
        "ms p50",
    ));
    for row in &r.runs {
        s.push_str(&format!(
            "{:<w$} {:>7} {:>8.4} {:>7} {:>9} {:>8} {:>7} {:>7} {:>7.1} {:>8.1} {:>8.1} {:>8.2} {:>8.2}\n",
            label(row),
            row.samples,
            row.peak_force_n,
            cell(row.ripple_ratio_full, 1.0, 2),
            cell(row.ripple_amplitude_full_n, 1e3, 4),
            cell(row.hold_variation_full_rel, 100.0, 3),
            row.flagged_samples,
            format!("{}/{}", row.failed_steps, row.failed_full_steps),
            row.model_age_max_ms,
            row.sample_us_p50,
            row.sample_us_p99,
            row.step_ms_p50,
            row.full_step_ms_p50,
        ));
    }
    s.push_str("\nlargest error of a sample (time, instrument, F_sample, F_full; N):\n");
    for row in &r.runs {
        let v = |f: Option<[f64; 3]>| {
            f.map_or("-".into(), |f| {
                format!("({:+.6}, {:+.6}, {:+.6})", f[0], f[1], f[2])
            })
        };
        s.push_str(&format!(
            "{:<w$} t = {} s, {}, {} vs {}\n",
            label(row),
            cell(row.max_error_at_s, 1.0, 3),
            row.max_error_instrument.as_deref().unwrap_or("-"),
            v(row.max_error_sample_n),
            v(row.max_error_full_n),
        ));
    }
    s
}

/// Runs the benchmark and prints JSON or the tables.
pub fn main(args: &HapticArgs) -> anyhow::Result<()> {
    let report = run(args)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", table(&report));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_gives_each_instrument_its_kth_trajectory() {
        let runs = plan(&[], &[]).unwrap();
        let of = |scene: &str| {
            runs.iter()
                .filter(|r| r.scene == scene)
                .map(|r| r.tracks.clone())
                .collect::<Vec<_>>()
        };
        let pair = |i: &str, t: &str| (i.to_owned(), t.to_owned());
        assert_eq!(
            of("sylvian"),
            vec![
                vec![
                    pair("left", "sylvian-open-left"),
                    pair("right", "sylvian-open-right")
                ],
                vec![
                    pair("left", "sylvian-expert-left"),
                    pair("right", "sylvian-expert-right")
                ],
                vec![
                    pair("left", "sylvian-careless-left"),
                    pair("right", "sylvian-careless-right")
                ]
            ]
        );
        assert_eq!(
            of("cube"),
            vec![
                vec![
                    pair("left", "cube-press-left"),
                    pair("right", "cube-press-right")
                ],
                vec![pair("left", "cube-press-hold-retract-left")]
            ]
        );
        assert_eq!(
            of("sylvian-arachnoid"),
            vec![
                vec![
                    pair("spatula", "sylvian-arachnoid-spatula"),
                    pair("blade", "sylvian-arachnoid-blade")
                ],
                vec![pair("spatula", "sylvian-arachnoid-careless-spatula")]
            ]
        );
        assert_eq!(
            of("sylvian-204k"),
            vec![vec![
                pair("left", "sylvian-204k-open-left"),
                pair("right", "sylvian-204k-open-right")
            ]]
        );
        assert_eq!(of("v-valley").len(), 2);
        assert_eq!(of("u-valley").len(), 1);
        assert_eq!(of("interhemispheric").len(), 1);
        let one = plan(&[], &["v-valley-fast-left".into()]).unwrap();
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].tracks, vec![pair("left", "v-valley-fast-left")]);
        let e = plan(&["nowhere".into()], &[]).unwrap_err().to_string();
        assert!(
            e.contains("--scene \"nowhere\"") && e.contains("sylvian"),
            "{e}"
        );
        let e = plan(&[], &["nothing".into()]).unwrap_err().to_string();
        assert!(e.contains("--trajectory \"nothing\""), "{e}");
    }

    /// A sinusoid's amplitude comes back at its frequency, with a large
    /// slow ramp beside it.
    #[test]
    fn amplitude_at_finds_a_sinusoid_beside_a_ramp() {
        let t: Vec<f64> = (0..2000).map(|k| k as f64 * 1e-3).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|&t| 0.3 * t + 1e-3 * (2.0 * std::f64::consts::PI * 50.0 * t + 0.4).sin())
            .collect();
        let a = amplitude_at(&t, &x, 50.0).unwrap();
        assert!((a - 1e-3).abs() < 2e-5, "{a}");
        let flat: Vec<f64> = t.iter().map(|&t| 0.3 * t).collect();
        assert!(amplitude_at(&t, &flat, 50.0).unwrap() < 1e-6);
    }

    /// F = k d on the way in and out: no hysteresis; a retraction that
    /// loses the force at once: the whole force.
    #[test]
    fn hysteresis_compares_the_branches_at_equal_depth() {
        let deepest = 3e-3;
        // In by 0.1 mm a sample, held, out by 0.07 mm a sample from 2.93 mm
        // to 0.15 mm above the surface.
        let mut depth: Vec<f64> = (0..30).map(|k| k as f64 * 1e-4).collect();
        depth.extend(vec![deepest; 10]);
        depth.extend((0..45).rev().map(|k| k as f64 * 0.7e-4 - 0.15e-3));
        let elastic: Vec<f64> = depth.iter().map(|&d| 100.0 * d.max(0.0)).collect();
        assert!(hysteresis_n(&depth, &elastic, 0.0).unwrap() < 1e-12);
        let last = depth.iter().rposition(|&d| d == deepest).unwrap();
        let lost: Vec<f64> = (0..depth.len())
            .map(|k| if k > last { 0.0 } else { elastic[k] })
            .collect();
        // The press at 2.9 mm (0.29 N) against nothing on the way out.
        let h = hysteresis_n(&depth, &lost, 0.0).unwrap();
        assert!((h - 0.29).abs() < 1e-9, "{h}");
        assert!(hysteresis_n(&depth, &elastic, 4e-3).is_none());
    }
}
