//! The loops' drivers, each on the thread [`Simulation::start`] spawns: the
//! free-running deformation loop (a step whenever a pose changed and the
//! interval has passed) and the stepped loop (the steps and the force
//! samples of each time in order, [`super::stepped::SteppedRunner`]).

use super::engine::StepEngine;
use super::pose::PoseError;
use super::stepped::{self, StepDone, SteppedRunner};
use super::{Mode, Pending, Simulation};
use nalgebra::Isometry3;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

impl Simulation {
    /// Free-running: a step whenever a pose changed and the interval has
    /// passed.
    pub(super) fn deformation_loop(self: Arc<Self>, mut engine: StepEngine) {
        let dt = self.scene.loops.deformation_interval_s;
        let n = self.scene.instruments.len();
        let mut seen_versions = vec![u64::MAX; n];
        let mut last_start = Instant::now();
        let homes: Vec<Isometry3<f64>> =
            (0..n).map(|i| stepped::home_pose(&self.scene, i)).collect();
        loop {
            let mut poses = Vec::with_capacity(n);
            let mut histories = Vec::with_capacity(n);
            {
                let mut inputs = self.inputs.lock().expect("inputs lock");
                loop {
                    if self.shutdown.load(Ordering::SeqCst) {
                        return;
                    }
                    if inputs.reset {
                        break;
                    }
                    let changed = inputs
                        .per_instrument
                        .iter()
                        .zip(&seen_versions)
                        .any(|(s, &v)| s.latest().version != v);
                    let due = last_start.elapsed().as_secs_f64() >= dt;
                    if changed && due {
                        break;
                    }
                    let wait = if changed {
                        Duration::from_secs_f64((dt - last_start.elapsed().as_secs_f64()).max(0.0))
                    } else {
                        Duration::from_millis(50)
                    };
                    inputs = self
                        .inputs_changed
                        .wait_timeout(inputs, wait)
                        .expect("inputs lock")
                        .0;
                }
                if inputs.reset {
                    inputs.reset = false;
                    drop(inputs);
                    let rest = Arc::new(engine.rest(self.started.elapsed().as_secs_f64()));
                    let frame = rest.frame;
                    self.publish(rest);
                    self.finish_reset(frame);
                    continue;
                }
                for i in 0..n {
                    let slot = &inputs.per_instrument[i];
                    seen_versions[i] = slot.latest().version;
                    match slot.latest().pose.as_ref().filter(|_| slot.claimed) {
                        Some((p, h)) => {
                            poses.push(p.pose);
                            histories.push(Some(h.clone()));
                        }
                        None => {
                            poses.push(homes[i]);
                            histories.push(None);
                        }
                    }
                }
            }
            last_start = Instant::now();
            let _span = tracing::debug_span!("deformation_step").entered();
            let prev = self.snapshot();
            // The step's time is the instant it was due, not a reading
            // taken later: a thread preempted between the two would put
            // two frames less than the interval apart.
            let sim_time = last_start
                .saturating_duration_since(self.started)
                .as_secs_f64();
            let (snap, report) = engine.step(&prev, sim_time, &poses, histories);
            let step_us = last_start.elapsed().as_secs_f64() * 1e6;
            self.note_step(&StepDone {
                snapshot: Arc::new(snap),
                report,
                step_us,
            });
        }
    }

    /// Stepped: answers the poses of each time once every claimed
    /// instrument has sent its next one.
    pub(super) fn stepped_loop(self: Arc<Self>, mut runner: SteppedRunner) {
        let mut answers = Vec::new();
        loop {
            let mut batch: Vec<(usize, Pending)> = Vec::new();
            {
                let mut inputs = self.inputs.lock().expect("inputs lock");
                loop {
                    if self.shutdown.load(Ordering::SeqCst) {
                        return;
                    }
                    if inputs.reset {
                        break;
                    }
                    for (i, slot) in inputs.per_instrument.iter_mut().enumerate() {
                        let q = slot.queued_mut();
                        if q.ended && q.poses.is_empty() {
                            q.ended = false;
                            runner.end(i);
                        }
                    }
                    let ever = inputs
                        .per_instrument
                        .iter()
                        .filter(|s| s.ever_claimed)
                        .count();
                    let claimed = || inputs.per_instrument.iter().filter(|s| s.claimed);
                    let any = claimed().any(|s| !s.queued().poses.is_empty());
                    let all = claimed().all(|s| !s.queued().poses.is_empty());
                    // An ended stream's poses still queued are answered too.
                    let leftover = inputs
                        .per_instrument
                        .iter()
                        .any(|s| !s.claimed && !s.queued().poses.is_empty());
                    let clients = match self.mode {
                        Mode::Stepped { clients } => clients.max(1),
                        Mode::FreeRunning => 1,
                    };
                    if ever >= clients && ((any && all) || leftover) {
                        break;
                    }
                    inputs = self.inputs_changed.wait(inputs).expect("inputs lock");
                }
                if inputs.reset {
                    inputs.reset = false;
                    drop(inputs);
                    let mut frame = 0;
                    runner.reset(&mut |done| {
                        frame = done.snapshot.frame;
                        self.publish(done.snapshot.clone());
                    });
                    self.finish_reset(frame);
                    continue;
                }
                let t = inputs
                    .per_instrument
                    .iter()
                    .filter_map(|s| s.queued().poses.front().map(|p| p.pose.t_s))
                    .fold(f64::INFINITY, f64::min);
                for (i, slot) in inputs.per_instrument.iter_mut().enumerate() {
                    let q = slot.queued_mut();
                    if q.poses.front().is_some_and(|p| p.pose.t_s == t) {
                        batch.push((i, q.poses.pop_front().expect("front checked")));
                    }
                }
            }
            let t = batch[0].1.pose.t_s;
            if let Some(clock) = runner.clock().filter(|&c| t < c) {
                for (_, p) in batch {
                    self.rejected.fetch_add(1, Ordering::Relaxed);
                    p.reply.send(Err(PoseError::BehindClock { got: t, clock }));
                }
                continue;
            }
            let poses: Vec<(usize, Isometry3<f64>)> =
                batch.iter().map(|(i, p)| (*i, p.pose.pose)).collect();
            answers.clear();
            runner.tick(t, &poses, &mut |done| self.note_step(done), &mut answers);
            for ((_, p), a) in batch.into_iter().zip(&answers) {
                let out = self.answer(
                    &p.pose,
                    &a.force,
                    a.frame,
                    a.model_age_s,
                    a.solver_failed,
                    a.compute_us,
                );
                self.force_latency.record(a.compute_us);
                self.force_samples.fetch_add(1, Ordering::Relaxed);
                p.reply.send(Ok(out));
            }
        }
    }
}
