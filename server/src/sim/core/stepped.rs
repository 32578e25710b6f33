//! The stepped runner: a session on the pose timestamps instead of the wall
//! clock, so that the server's stepped mode, replays and `fissure study`
//! give the same numbers every run (DESIGN.md section 4). One runner
//! serves all of them: the server's stepped mode feeds it from the haptic
//! streams, the study from its scenario.
//!
//! Time: the clock starts at the first time the runner is given (after a
//! start or a reset), `t_0`; deformation step `k >= 1` happens at
//! `t_k = t_0 + k dt` (computed as `t_0 + (k as f64) * dt`, so that both
//! sides of every comparison agree to the bit). Step `k` uses, per
//! instrument, the latest pose with `t <= t_k` and the force loop's
//! history after it (the home pose, and its own history, when there is
//! none or the instrument's stream ended before `t_k`). A force sample at
//! pose time `t` uses the state of the last step strictly before `t`
//! ([`step_before`]).
//!
//! A [`SteppedRunner::tick`] answers the poses of one time `t`: it runs the
//! steps due before `t`, queries every instrument posed at `t` against
//! that state, and only then solves each one's contact problem, coupled
//! with the others' rows at `t` (and, for an instrument not posed at `t`,
//! its rows at its latest earlier pose): the instruments of one time see
//! each other symmetrically, whatever order their poses came in.

use super::engine::{History, Model, StepEngine, StepReport};
use super::force_loop::{ForceLoop, SampleForce};
use super::snapshot::Snapshot;
use crate::scene::Scene;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

/// The last stepped-mode step strictly before time `t` (s, on a clock that
/// starts at 0): the largest `k >= 0` with `k * dt < t`, or 0. Computed
/// with the same products `k as f64 * dt` as the runner's step times.
pub fn step_before(t: f64, dt: f64) -> u64 {
    if t.is_nan() || t <= 0.0 {
        return 0;
    }
    let mut k = (t / dt).ceil().max(1.0) as u64 - 1;
    while k > 0 && k as f64 * dt >= t {
        k -= 1;
    }
    while (k + 1) as f64 * dt < t {
        k += 1;
    }
    k
}

/// One deformation step the runner ran.
#[derive(Debug, Clone)]
pub struct StepDone {
    /// The snapshot it published.
    pub snapshot: Arc<Snapshot>,
    /// Its report (`None` when the step failed and kept the last state).
    pub report: Option<StepReport>,
    /// Its wall time, us.
    pub step_us: f64,
}

/// One answered pose.
#[derive(Debug, Clone, Copy)]
pub struct Answer {
    /// The instrument.
    pub instrument: usize,
    /// The force sample.
    pub force: SampleForce,
    /// The frame whose state gave it.
    pub frame: u64,
    /// Pose time minus that frame's time, s.
    pub model_age_s: f64,
    /// Whether that frame's step failed.
    pub solver_failed: bool,
    /// Compute time of this instrument's sample (query and solve), us.
    pub compute_us: f64,
}

#[derive(Debug, Default)]
struct Track {
    /// Answered poses with the history after each, oldest first.
    log: VecDeque<(f64, Isometry3<f64>, History)>,
    /// Its stream ended after this pose time.
    ended_at: Option<f64>,
    /// Whether its force loop holds rows of a pose (an answered pose of a
    /// stream that has not ended).
    live: bool,
}

/// The stepped runner (module documentation).
pub struct SteppedRunner {
    scene: Scene,
    model: Arc<Model>,
    engine: StepEngine,
    loops: Vec<ForceLoop>,
    snapshot: Arc<Snapshot>,
    tracks: Vec<Track>,
    homes: Vec<Isometry3<f64>>,
    dt: f64,
    origin: Option<f64>,
    clock: Option<f64>,
    k: u64,
    queried: Vec<bool>,
}

impl std::fmt::Debug for SteppedRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SteppedRunner")
            .field("scene", &self.scene.name)
            .field("k", &self.k)
            .field("clock", &self.clock)
            .finish_non_exhaustive()
    }
}

/// The home pose of instrument `i` of `scene`.
pub fn home_pose(scene: &Scene, i: usize) -> Isometry3<f64> {
    let spec = &scene.instruments[i];
    let [w, x, y, z] = spec.home_orientation;
    let [px, py, pz] = spec.home_position_m;
    Isometry3::from_parts(
        Translation3::new(px, py, pz),
        UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
    )
}

impl SteppedRunner {
    /// A runner over `engine` (whose next frame is the rest state it
    /// publishes now); `loops[i]` is instrument `i`'s force loop.
    pub fn new(scene: &Scene, mut engine: StepEngine, loops: Vec<ForceLoop>) -> Self {
        let model = engine.model().clone();
        let snapshot = Arc::new(engine.rest(0.0));
        let n = scene.instruments.len();
        Self {
            homes: (0..n).map(|i| home_pose(scene, i)).collect(),
            scene: scene.clone(),
            model,
            engine,
            loops,
            snapshot,
            tracks: (0..n).map(|_| Track::default()).collect(),
            dt: scene.loops.deformation_interval_s,
            origin: None,
            clock: None,
            k: 0,
            queried: vec![false; n],
        }
    }

    /// A runner with the scene's own engine and force loops.
    pub fn for_scene(
        scene: &Scene,
        model: Arc<Model>,
        columns: crate::fem::compliance::ColumnPolicy,
    ) -> Result<Self, super::engine::ModelError> {
        let engine = StepEngine::new(scene, model.clone(), columns, None, None)?;
        let loops = (0..scene.instruments.len())
            .map(|i| ForceLoop::new(scene, &model, i, None))
            .collect();
        Ok(Self::new(scene, engine, loops))
    }

    /// The latest snapshot.
    pub fn snapshot(&self) -> &Arc<Snapshot> {
        &self.snapshot
    }

    /// The model.
    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// The time of the last answered tick, s (`None` before the first).
    pub fn clock(&self) -> Option<f64> {
        self.clock
    }

    /// Steps run since the clock started.
    pub fn steps(&self) -> u64 {
        self.k
    }

    /// Time of step `k`, s.
    fn step_time(&self, k: u64) -> f64 {
        self.origin.unwrap_or(0.0) + k as f64 * self.dt
    }

    /// Runs the steps strictly before `t` (s), calling `on_step` after
    /// each.
    pub fn advance(&mut self, t: f64, on_step: &mut dyn FnMut(&StepDone)) {
        self.origin.get_or_insert(t);
        while self.step_time(self.k + 1) < t {
            self.k += 1;
            let t_k = self.step_time(self.k);
            self.run_step(t_k, on_step);
        }
    }

    /// Runs the steps with `t_k <= until` (the end of a session).
    pub fn finish(&mut self, until: f64, on_step: &mut dyn FnMut(&StepDone)) {
        if self.origin.is_none() {
            return;
        }
        while self.step_time(self.k + 1) <= until {
            self.k += 1;
            let t_k = self.step_time(self.k);
            self.run_step(t_k, on_step);
        }
    }

    fn run_step(&mut self, t_k: f64, on_step: &mut dyn FnMut(&StepDone)) {
        let n = self.tracks.len();
        let mut poses = Vec::with_capacity(n);
        let mut histories = Vec::with_capacity(n);
        for i in 0..n {
            let track = &mut self.tracks[i];
            while track.log.len() >= 2 && track.log[1].0 <= t_k {
                track.log.pop_front();
            }
            let chosen = match (track.log.front(), track.ended_at) {
                (Some(_), Some(end)) if t_k > end => None,
                (Some((t, p, h)), _) if *t <= t_k => Some((*p, h.clone())),
                _ => None,
            };
            match chosen {
                Some((p, h)) => {
                    poses.push(p);
                    histories.push(Some(h));
                }
                None => {
                    poses.push(self.homes[i]);
                    histories.push(None);
                }
            }
        }
        let started = Instant::now();
        let (snap, report) = self.engine.step(&self.snapshot, t_k, &poses, histories);
        let step_us = started.elapsed().as_secs_f64() * 1e6;
        self.snapshot = Arc::new(snap);
        on_step(&StepDone {
            snapshot: self.snapshot.clone(),
            report,
            step_us,
        });
    }

    /// Answers the poses of time `t` (`poses[j] = (instrument, pose)`, one
    /// per instrument at most): runs the steps due first, then queries every
    /// posed instrument, then solves each (module documentation). Appends
    /// one [`Answer`] per pose to `answers`, in the order of `poses`.
    pub fn tick(
        &mut self,
        t: f64,
        poses: &[(usize, Isometry3<f64>)],
        on_step: &mut dyn FnMut(&StepDone),
        answers: &mut Vec<Answer>,
    ) {
        self.advance(t, on_step);
        self.clock = Some(t);
        let snap = self.snapshot.clone();
        // Until the session's first step the rest frame stands for its
        // origin (a reset publishes it at the last session's time).
        let frame_time = if self.k == 0 {
            self.origin.unwrap_or(snap.sim_time_s)
        } else {
            snap.sim_time_s
        };
        let model = self.model.clone();
        let mut spent = vec![0.0; poses.len()];
        self.queried.fill(false);
        for (j, (i, pose)) in poses.iter().enumerate() {
            let started = Instant::now();
            self.loops[*i].query(&model, &snap, pose);
            spent[j] = started.elapsed().as_secs_f64() * 1e6;
            self.queried[*i] = true;
            self.tracks[*i].live = true;
            self.tracks[*i].ended_at = None;
        }
        for (j, (i, pose)) in poses.iter().enumerate() {
            let started = Instant::now();
            let (me, rest) = split_out(&mut self.loops, *i);
            let tracks = &self.tracks;
            let others = |j: usize| match rest.get(j).copied().flatten() {
                Some(l) if tracks[j].live => Some(l.rows()),
                _ => None,
            };
            let force = me.solve(&model, &snap, &others, &pose.translation.vector);
            spent[j] += started.elapsed().as_secs_f64() * 1e6;
            answers.push(Answer {
                instrument: *i,
                force,
                frame: snap.frame,
                model_age_s: t - frame_time,
                solver_failed: snap.solver_error.is_some(),
                compute_us: spent[j],
            });
        }
        for (i, pose) in poses {
            let h = self.loops[*i].history().clone();
            self.tracks[*i].log.push_back((t, *pose, h));
        }
    }

    /// Instrument `i`'s stream ended: steps after its last answered pose
    /// see it at home, and its rows leave the others' problems.
    pub fn end(&mut self, i: usize) {
        let track = &mut self.tracks[i];
        track.ended_at = Some(track.log.back().map_or(f64::NEG_INFINITY, |e| e.0));
        track.live = false;
    }

    /// Back to rest (the next frame), the clock and every history cleared:
    /// the next tick starts a new session from its own time.
    pub fn reset(&mut self, on_step: &mut dyn FnMut(&StepDone)) {
        let t = self.snapshot.sim_time_s;
        self.snapshot = Arc::new(self.engine.rest(t));
        for (track, l) in self.tracks.iter_mut().zip(&mut self.loops) {
            *track = Track::default();
            l.clear(&self.model);
        }
        self.origin = None;
        self.clock = None;
        self.k = 0;
        on_step(&StepDone {
            snapshot: self.snapshot.clone(),
            report: None,
            step_us: 0.0,
        });
    }
}

/// `loops[i]` mutably, and every loop as `Some` but `i` (`None`).
fn split_out(loops: &mut [ForceLoop], i: usize) -> (&mut ForceLoop, Vec<Option<&ForceLoop>>) {
    let (head, tail) = loops.split_at_mut(i);
    let (me, tail) = tail.split_first_mut().expect("instrument index in range");
    let mut rest: Vec<Option<&ForceLoop>> = head.iter().map(Some).collect();
    rest.push(None);
    rest.extend(tail.iter().map(Some));
    (me, rest)
}

#[cfg(test)]
mod tests {
    use super::step_before;

    #[test]
    fn step_before_is_consistent_with_step_times() {
        let dt = 0.02;
        assert_eq!(step_before(0.0, dt), 0);
        assert_eq!(step_before(0.001, dt), 0);
        assert_eq!(step_before(0.02, dt), 0);
        assert_eq!(step_before(0.021, dt), 1);
        // 0.14 / 0.02 rounds to 7.000000000000001: still step 6.
        assert_eq!(step_before(0.14, dt), 6);
        for i in 1..100_000u64 {
            let t = i as f64 * 1e-3;
            let k = step_before(t, dt);
            assert!(
                (k as f64 * dt) < t && ((k + 1) as f64 * dt) >= t,
                "t = {t}, k = {k}"
            );
        }
    }
}
