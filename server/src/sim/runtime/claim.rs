//! A client's exclusive claim of one instrument ([`Claim`]): its force
//! samples, answered by its own force loop (free-running: the collision
//! query, the row exchange with the other instruments' loops, the coupled
//! solve) or by the stepped loop, which it queues the pose for and waits
//! on. Released on drop.

use super::force_loop::{ForceLoop, HeldRows};
use super::pose::{self, PoseError, RawPose, TimedPose};
use super::{ForceOut, Lane, Pending, Reply, Simulation, flags, priority};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// An exclusive claim of one instrument: its force loop. Released on drop.
pub struct Claim {
    pub(super) sim: Arc<Simulation>,
    pub(super) index: usize,
    pub(super) name: String,
    pub(super) last: Option<TimedPose>,
    pub(super) resets_seen: u64,
    /// Free-running: the instrument's force loop (stepped: the runner's).
    pub(super) force_loop: Option<ForceLoop>,
    /// Free-running: the other instruments' rows read for one sample.
    pub(super) held: HeldRows,
    pub(super) reply: Arc<Reply>,
}

impl std::fmt::Debug for Claim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Claim")
            .field("instrument", &self.name)
            .finish_non_exhaustive()
    }
}

impl Claim {
    /// Prepares the calling thread to run this claim's force loop: asks for
    /// the real-time priority of [`SimOptions::force_loop_rt_priority`]. Call
    /// once, on the thread that will call [`Claim::force_sample`]. Whether it
    /// took is logged (a refusal once per process, at `warn`).
    pub fn enter_force_thread(&self) {
        static REFUSED: AtomicBool = AtomicBool::new(false);
        let asked = self.sim.options.force_loop_rt_priority;
        match priority::raise_current_thread(asked) {
            Ok(true) => {
                tracing::debug!(instrument = %self.name, priority = asked, "force loop runs SCHED_FIFO")
            }
            Ok(false) => {}
            Err(why) => {
                if !REFUSED.swap(true, Ordering::Relaxed) {
                    tracing::warn!(
                        priority = asked,
                        %why,
                        "force loops run at normal priority: no real-time scheduling here \
                         (grant CAP_SYS_NICE or an RLIMIT_RTPRIO allowance, or pass 0 to stop asking)"
                    );
                }
            }
        }
    }

    /// The claimed instrument's name.
    pub fn instrument(&self) -> &str {
        &self.name
    }

    /// Answers one pose: validates it (a rejected pose changes nothing), then
    /// the force loop ([`force_loop`]). Blocking in stepped mode (the stepped
    /// runner answers once every claimed instrument has sent its pose of that
    /// time); never blocking otherwise.
    pub fn force_sample(&mut self, raw: &RawPose) -> Result<ForceOut, PoseError> {
        let _span = tracing::trace_span!("force_sample", instrument = %self.name).entered();
        let t_start = Instant::now();
        let sim = self.sim.clone();
        // A reset starts a new session: its timestamps may start over.
        let resets = sim.resets.lock().expect("resets lock").0;
        if resets != self.resets_seen {
            self.resets_seen = resets;
            self.last = None;
        }
        let pose = match pose::validate(raw, self.last.as_ref()) {
            Ok(p) => p,
            Err(e) => {
                sim.rejected.fetch_add(1, Ordering::Relaxed);
                return Err(e);
            }
        };
        let mut jump = 0;
        if let Some(last) = &self.last {
            let d = (pose.pose.translation.vector - last.pose.translation.vector).norm();
            if d > sim.scene.loops.max_jump_m {
                jump = flags::POSE_JUMP;
            }
        }
        let mut out = if sim.is_stepped() {
            self.stepped_sample(&pose)?
        } else {
            self.free_sample(&pose, t_start)
        };
        out.safety_flags |= jump;
        self.last = Some(pose);
        Ok(out)
    }

    fn stepped_sample(&mut self, pose: &TimedPose) -> Result<ForceOut, PoseError> {
        let sim = &self.sim;
        *self.reply.slot.lock().expect("reply lock") = None;
        {
            let mut inputs = sim.inputs.lock().expect("inputs lock");
            inputs.per_instrument[self.index]
                .queued_mut()
                .poses
                .push_back(Pending {
                    pose: *pose,
                    reply: self.reply.clone(),
                });
        }
        sim.inputs_changed.notify_all();
        let mut slot = self.reply.slot.lock().expect("reply lock");
        loop {
            if let Some(r) = slot.take() {
                return r;
            }
            if sim.shutdown.load(Ordering::SeqCst) {
                drop(slot);
                sim.fail_pending();
                slot = self.reply.slot.lock().expect("reply lock");
                if let Some(r) = slot.take() {
                    return r;
                }
                return Err(PoseError::NotAnswered("the server is shutting down".into()));
            }
            slot = self
                .reply
                .ready
                .wait_timeout(slot, Duration::from_millis(100))
                .expect("reply lock")
                .0;
        }
    }

    fn free_sample(&mut self, pose: &TimedPose, t_start: Instant) -> ForceOut {
        let sim = self.sim.clone();
        let snap = sim.snapshot();
        let fl = self
            .force_loop
            .as_mut()
            .expect("free-running claims have a force loop");
        let t_query = Instant::now();
        fl.query(&sim.model, &snap, &pose.pose);
        sim.force_collision_latency
            .record(t_query.elapsed().as_secs_f64() * 1e6);
        sim.exchange.publish(self.index, fl.rows());
        sim.exchange.gather(self.index, &mut self.held);
        let held = &self.held;
        let others = |j: usize| held.of(j);
        let sample = fl.solve(&sim.model, &snap, &others, &pose.pose.translation.vector);
        self.held.clear();
        {
            let mut inputs = sim.inputs.lock().expect("inputs lock");
            let slot = inputs.per_instrument[self.index].latest_mut();
            slot.version += 1;
            match slot.pose.as_mut() {
                Some((p, h)) => {
                    // Reuse the slot's flags (no allocation per sample).
                    *p = *pose;
                    h.copy_from(fl.history());
                }
                None => slot.pose = Some((*pose, fl.history().clone())),
            }
        }
        sim.inputs_changed.notify_all();
        let model_age_s = snap.published.elapsed().as_secs_f64();
        let compute_us = t_start.elapsed().as_secs_f64() * 1e6;
        sim.force_latency.record(compute_us);
        sim.force_samples.fetch_add(1, Ordering::Relaxed);
        sim.answer(
            pose,
            &sample,
            snap.frame,
            model_age_s,
            snap.solver_error.is_some(),
            compute_us,
        )
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        {
            let mut inputs = self.sim.inputs.lock().expect("inputs lock");
            let slot = &mut inputs.per_instrument[self.index];
            slot.claimed = false;
            match &mut slot.lane {
                Lane::Latest(l) => {
                    l.pose = None;
                    l.version += 1;
                }
                Lane::Queued(q) => q.ended = true,
            }
        }
        self.sim.exchange.release(self.index);
        self.sim.inputs_changed.notify_all();
        tracing::info!(instrument = %self.name, "instrument released");
    }
}
