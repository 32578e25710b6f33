//! The force loop and the deformation loop, their shared state and recording
//! (DESIGN.md section 4).
//!
//! * The **deformation loop** runs on its own thread: latest poses -> collision
//!   with culling for every instrument -> FEM step -> a [`Snapshot`] swapped in
//!   atomically (latest wins) and a [`Frame`] sent on a `watch` channel (slow
//!   watchers see only the latest frame). With the CPU BVH, the snapshot also
//!   carries the tree refitted to its surface, which every force loop casts on
//!   read-only. The thread and its rayon pool run at a lower priority
//!   ([`priority`], [`SimOptions::deformation_nice`]) so that force samples
//!   preempt the solver.
//! * The **force loop** of a claimed instrument ([`Claim::force_sample`]) runs in
//!   the caller's thread: a fresh collision query (sequential, on the
//!   snapshot's tree) against the latest snapshot's surface and the local model
//!   of its step. In free-running mode it never
//!   waits for the deformation loop.
//! * **Stepped mode** makes runs reproducible: deformation step `k` happens at
//!   simulation time `t_k = k * dt` and uses, per instrument, the latest pose
//!   with `t <= t_k`; a force sample at pose time `t` uses frame
//!   `ceil(t / dt) - 1` (the last step strictly before `t`) and waits for it.
//!   Step `k` runs once every instrument that is claimed has been given a pose
//!   with `t > t_k` (or its stream ended), and at least
//!   [`SimOptions::stepped_clients`] instruments have been claimed.

pub mod engine;
pub mod local_model;
pub mod pose;
pub mod priority;
pub mod recording;
pub mod snapshot;
pub mod stats;

use crate::scene::{HistoryMode, Scene};
use engine::{ContactQuery, Deformer, Model};
use faer::Par;
use local_model::ForceWorkspace;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use pose::{PoseError, RawPose, TimedPose};
use snapshot::{Frame, Snapshot, StepTimings};
use stats::{LatencyRecorder, StatsSummary};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Safety flags of a force sample (same bits as `fissure.v1.SafetyFlag`).
pub mod flags {
    /// Force above the scene's safe threshold.
    pub const FORCE_ABOVE_THRESHOLD: u32 = 1;
    /// Force clamped to the scene's maximum.
    pub const FORCE_CLAMPED: u32 = 2;
    /// Deformation model older than 10 deformation intervals.
    pub const MODEL_STALE: u32 = 4;
    /// The last deformation step failed.
    pub const SOLVER_FAILED: u32 = 8;
    /// The pose jumped farther than the scene allows in one sample.
    pub const POSE_JUMP: u32 = 16;
}

/// Options of a simulation beyond the scene file.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Override of the scene's stepped mode.
    pub stepped: Option<bool>,
    /// In stepped mode, the number of instruments that must have been claimed
    /// before the first step runs (so that runs with several clients are
    /// reproducible whatever order they connect in).
    pub stepped_clients: usize,
    /// Session recording file, if any.
    pub recording: Option<PathBuf>,
    /// Largest number of concurrent watchers.
    pub max_watchers: usize,
    /// Nice value of the deformation thread and its rayon pool (Linux; 0
    /// leaves them at the process's priority). Higher than the force loops'
    /// so that a force sample preempts the solver ([`priority`]).
    pub deformation_nice: i32,
    /// Real-time (`SCHED_FIFO`) priority each force loop asks for, 1-99; 0
    /// asks for none. Without the privilege a loop runs at normal priority
    /// ([`priority`]).
    pub force_loop_rt_priority: u8,
}

/// Default of [`SimOptions::deformation_nice`].
pub const DEFAULT_DEFORMATION_NICE: i32 = 10;

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            stepped: None,
            stepped_clients: 1,
            recording: None,
            max_watchers: 16,
            deformation_nice: DEFAULT_DEFORMATION_NICE,
            force_loop_rt_priority: priority::DEFAULT_FORCE_LOOP_RT_PRIORITY,
        }
    }
}

/// Errors of building a simulation.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The model could not be built.
    #[error("building the model: {0}")]
    Model(String),
    /// The solver could not be set up.
    #[error("setting up the solver: {0}")]
    Solver(String),
    /// The recording could not be opened.
    #[error("opening the recording {path}: {source}")]
    Recording {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Why an instrument cannot be claimed.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum ClaimError {
    /// No instrument of that name in the scene.
    #[error("the scene has no instrument named {name:?} (it has: {known})")]
    Unknown { name: String, known: String },
    /// Another client holds it.
    #[error("instrument {0:?} is already claimed by another client")]
    Taken(String),
    /// The server is shutting down.
    #[error("the server is shutting down")]
    ShuttingDown,
}

/// The answer to one pose.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ForceOut {
    /// Pose sequence answered.
    pub sequence: u64,
    /// Pose time answered, s.
    pub t_s: f64,
    /// Force of the tissue on the instrument, N.
    pub force_n: Vector3<f64>,
    /// Torque about the handle point, N m.
    pub torque_nm: Vector3<f64>,
    /// Surface vertices in contact.
    pub contact_count: u32,
    /// Frame whose local model was used.
    pub model_frame: u64,
    /// Age of that model, s (simulation time in stepped mode).
    pub model_age_s: f64,
    /// Safety flags.
    pub safety_flags: u32,
    /// Server compute time, us.
    pub compute_us: f64,
}

/// Per-instrument input state shared between its force loop and the
/// deformation loop.
#[derive(Debug, Clone)]
struct InstrumentInput {
    claimed: bool,
    /// Ever claimed (stepped mode counts these).
    ever_claimed: bool,
    /// Latest accepted pose and the force-rate history after it.
    latest: Option<(TimedPose, engine::History)>,
    /// Stepped mode: accepted poses (with history after each), oldest first.
    log: VecDeque<(TimedPose, engine::History)>,
    /// Stepped mode: time of the pose the force loop is working on.
    reached_t: f64,
    /// Stepped mode: the stream ended at this pose time.
    ended_at: Option<f64>,
    /// Bumped at each accepted pose (free-running: has anything changed?).
    version: u64,
}

struct Inputs {
    per_instrument: Vec<InstrumentInput>,
    reset: bool,
}

/// A running simulation: the model, the deformation thread, the shared state.
pub struct Simulation {
    scene: Scene,
    model: Arc<Model>,
    stepped: bool,
    options: SimOptions,
    snapshot: RwLock<Arc<Snapshot>>,
    frames: tokio::sync::watch::Sender<Arc<Frame>>,
    inputs: Mutex<Inputs>,
    inputs_changed: Condvar,
    published: Condvar,
    published_lock: Mutex<u64>,
    shutdown: AtomicBool,
    thread: Mutex<Option<JoinHandle<()>>>,
    started: Instant,
    force_latency: LatencyRecorder,
    step_latency: LatencyRecorder,
    force_samples: AtomicU64,
    rejected: AtomicU64,
    failed_steps: AtomicU64,
    watchers: AtomicU64,
    recorder: Option<recording::Recorder>,
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("scene", &self.scene.name)
            .finish_non_exhaustive()
    }
}

impl Simulation {
    /// Builds the model and the solver, publishes the rest state as frame 0 and
    /// starts the deformation thread.
    pub fn start(mut scene: Scene, options: SimOptions) -> Result<Arc<Self>, SimError> {
        let loading = Instant::now();
        crate::progress::stage(format_args!("scene {}: building the model", scene.name));
        let model = Arc::new(Model::build(&scene)?);
        crate::progress::stage(format_args!(
            "scene {}: setting up the {} solver ({} nodes, {} tetrahedra)",
            scene.name,
            scene.solver.strategy.name(),
            model.mesh.nodes.len(),
            model.mesh.tets.len()
        ));
        let deformer = Deformer::new(&scene, &model)?;
        let stepped = options.stepped.unwrap_or(scene.loops.stepped);
        // The scene as run: GetScene and the recording header report the
        // effective mode, not the file's.
        scene.loops.stepped = stepped;
        let recorder = match &options.recording {
            Some(path) => Some(
                recording::Recorder::create(
                    path,
                    &crate::service::convert::scene_description(&scene, &model),
                )
                .map_err(|source| SimError::Recording {
                    path: path.clone(),
                    source,
                })?,
            ),
            None => None,
        };
        let mut bvhs = engine::SurfaceBvhs::new(&scene, &model);
        let mut rest = model.rest_snapshot(&scene);
        rest.surface_bvh = bvhs.as_mut().map(|b| b.current());
        let (frames, _) = tokio::sync::watch::channel(rest.frame_summary.clone());
        let n = scene.instruments.len();
        let sim = Arc::new(Self {
            model: model.clone(),
            stepped,
            options,
            snapshot: RwLock::new(Arc::new(rest)),
            frames,
            inputs: Mutex::new(Inputs {
                per_instrument: vec![
                    InstrumentInput {
                        claimed: false,
                        ever_claimed: false,
                        latest: None,
                        log: VecDeque::new(),
                        reached_t: f64::NEG_INFINITY,
                        ended_at: None,
                        version: 0,
                    };
                    n
                ],
                reset: false,
            }),
            inputs_changed: Condvar::new(),
            published: Condvar::new(),
            published_lock: Mutex::new(0),
            shutdown: AtomicBool::new(false),
            thread: Mutex::new(None),
            started: Instant::now(),
            force_latency: LatencyRecorder::default(),
            step_latency: LatencyRecorder::default(),
            force_samples: AtomicU64::new(0),
            rejected: AtomicU64::new(0),
            failed_steps: AtomicU64::new(0),
            watchers: AtomicU64::new(0),
            recorder,
            scene,
        });
        let worker = sim.clone();
        let handle = std::thread::Builder::new()
            .name("deformation-loop".into())
            .spawn(move || {
                let nice = worker.options.deformation_nice;
                priority::lower_current_thread(nice);
                match priority::deformation_pool(nice) {
                    Some(pool) => pool.install(|| worker.deformation_loop(deformer, bvhs)),
                    None => worker.deformation_loop(deformer, bvhs),
                }
            })
            .map_err(|e| SimError::Solver(format!("cannot start the deformation thread: {e}")))?;
        *sim.thread.lock().expect("thread lock") = Some(handle);
        crate::progress::done(format_args!(
            "scene {} loaded in {:.1} s",
            sim.scene.name,
            loading.elapsed().as_secs_f64()
        ));
        Ok(sim)
    }

    /// The scene as loaded.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The model (mesh, surface, instruments).
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Whether deformation steps follow pose timestamps.
    pub fn is_stepped(&self) -> bool {
        self.stepped
    }

    /// The latest snapshot.
    pub fn snapshot(&self) -> Arc<Snapshot> {
        self.snapshot.read().expect("snapshot lock").clone()
    }

    /// The largest number of concurrent watchers ([`SimOptions::max_watchers`]).
    pub fn max_watchers(&self) -> usize {
        self.options.max_watchers
    }

    /// A receiver of frames, latest-wins. Fails when the watcher limit is reached.
    pub fn watch(self: &Arc<Self>) -> Option<WatcherGuard> {
        let n = self.watchers.fetch_add(1, Ordering::SeqCst);
        if n as usize >= self.options.max_watchers {
            self.watchers.fetch_sub(1, Ordering::SeqCst);
            return None;
        }
        Some(WatcherGuard {
            sim: self.clone(),
            rx: self.frames.subscribe(),
        })
    }

    /// Claims an instrument for one haptic client; released when the claim drops.
    pub fn claim(self: &Arc<Self>, name: &str) -> Result<Claim, ClaimError> {
        if self.shutdown.load(Ordering::SeqCst) {
            return Err(ClaimError::ShuttingDown);
        }
        let Some((index, _)) = self.scene.instrument(name) else {
            return Err(ClaimError::Unknown {
                name: name.to_owned(),
                known: self
                    .scene
                    .instruments
                    .iter()
                    .map(|i| i.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        };
        {
            let mut inputs = self.inputs.lock().expect("inputs lock");
            let slot = &mut inputs.per_instrument[index];
            if slot.claimed {
                return Err(ClaimError::Taken(name.to_owned()));
            }
            slot.claimed = true;
            slot.ever_claimed = true;
            slot.ended_at = None;
            slot.reached_t = f64::NEG_INFINITY;
            slot.log.clear();
        }
        self.inputs_changed.notify_all();
        tracing::info!(instrument = name, "instrument claimed");
        Ok(Claim {
            sim: self.clone(),
            index,
            name: name.to_owned(),
            last: None,
            history: self.model.new_history(index),
            query: ContactQuery::new(&self.scene, Par::Seq),
            ws: ForceWorkspace::default(),
        })
    }

    /// Returns the tissue to rest and clears the histories (at the next step).
    pub fn reset(&self) -> u64 {
        let mut inputs = self.inputs.lock().expect("inputs lock");
        inputs.reset = true;
        drop(inputs);
        self.inputs_changed.notify_all();
        self.snapshot().frame + 1
    }

    /// Counters and latency percentiles.
    pub fn stats(&self) -> StatsSummary {
        use recording::RecordingGapExt as _;
        let claimed = {
            let inputs = self.inputs.lock().expect("inputs lock");
            self.scene
                .instruments
                .iter()
                .zip(&inputs.per_instrument)
                .filter(|(_, s)| s.claimed)
                .map(|(i, _)| i.name.clone())
                .collect()
        };
        StatsSummary {
            uptime_s: self.started.elapsed().as_secs_f64(),
            frames: self.snapshot().frame,
            force_samples: self.force_samples.load(Ordering::Relaxed),
            rejected_poses: self.rejected.load(Ordering::Relaxed),
            watchers: self.watchers.load(Ordering::Relaxed) as u32,
            claimed,
            force_compute: self.force_latency.summary(),
            deformation_step: self.step_latency.summary(),
            failed_steps: self.failed_steps.load(Ordering::Relaxed),
            recording_lost: self.recorder().map_or(0, |r| r.stats().lost.total()),
        }
    }

    /// Stops the deformation loop, flushes the recording, releases waiters.
    pub fn shutdown(&self) {
        self.shutdown.store(true, Ordering::SeqCst);
        self.inputs_changed.notify_all();
        self.published.notify_all();
        if let Some(handle) = self.thread.lock().expect("thread lock").take() {
            let _ = handle.join();
        }
        if let Some(rec) = &self.recorder {
            rec.flush();
        }
    }

    /// Counts a pose rejected before it reached a claim (a missing field, a
    /// stream over its rate), in the stats' `rejected_poses`.
    pub fn record_rejection(&self) {
        self.rejected.fetch_add(1, Ordering::Relaxed);
    }

    /// The session recorder, if recording.
    pub fn recorder(&self) -> Option<&recording::Recorder> {
        self.recorder.as_ref()
    }

    fn publish(&self, snap: Snapshot) {
        let frame = snap.frame_summary.clone();
        let number = snap.frame;
        *self.snapshot.write().expect("snapshot lock") = Arc::new(snap);
        self.frames.send_replace(frame.clone());
        if let Some(rec) = &self.recorder {
            rec.frame(&frame);
        }
        *self.published_lock.lock().expect("published lock") = number;
        self.published.notify_all();
    }

    /// Waits (stepped mode) until frame `k` or a later one is published.
    fn wait_for_frame(&self, k: u64) -> Arc<Snapshot> {
        let mut published = self.published_lock.lock().expect("published lock");
        while *published < k && !self.shutdown.load(Ordering::SeqCst) {
            published = self.published.wait(published).expect("published lock");
        }
        drop(published);
        self.snapshot()
    }

    fn home_pose(&self, index: usize) -> Isometry3<f64> {
        let spec = &self.scene.instruments[index];
        let [w, x, y, z] = spec.home_orientation;
        let [px, py, pz] = spec.home_position_m;
        Isometry3::from_parts(
            Translation3::new(px, py, pz),
            UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
        )
    }

    fn deformation_loop(
        self: Arc<Self>,
        mut deformer: Deformer,
        mut bvhs: Option<engine::SurfaceBvhs>,
    ) {
        let dt = self.scene.loops.deformation_interval_s;
        let n = self.scene.instruments.len();
        let mut query = ContactQuery::new(&self.scene, Par::rayon(0));
        let mut paper_history: Vec<engine::History> =
            (0..n).map(|i| self.model.new_history(i)).collect();
        let mut seen_versions = vec![u64::MAX; n];
        let mut k: u64 = 0;
        let mut last_start = Instant::now();
        loop {
            // 1. Wait for the inputs of the next step.
            let mut poses = Vec::with_capacity(n);
            let mut histories = Vec::with_capacity(n);
            let sim_time;
            {
                let mut inputs = self.inputs.lock().expect("inputs lock");
                loop {
                    if self.shutdown.load(Ordering::SeqCst) {
                        return;
                    }
                    if inputs.reset {
                        break;
                    }
                    if self.stepped {
                        // Same product as `step_before`.
                        let t_next = (k + 1) as f64 * dt;
                        let ever = inputs
                            .per_instrument
                            .iter()
                            .filter(|s| s.ever_claimed)
                            .count();
                        let any_active = inputs.per_instrument.iter().any(|s| s.claimed);
                        let ready = ever >= self.options.stepped_clients.max(1)
                            && any_active
                            && inputs.per_instrument.iter().all(|s| {
                                !s.claimed || s.reached_t > t_next || s.ended_at.is_some()
                            });
                        if ready {
                            break;
                        }
                        inputs = self.inputs_changed.wait(inputs).expect("inputs lock");
                    } else {
                        let changed = inputs
                            .per_instrument
                            .iter()
                            .zip(&seen_versions)
                            .any(|(s, &v)| s.version != v);
                        let due = last_start.elapsed().as_secs_f64() >= dt;
                        if changed && due {
                            break;
                        }
                        let wait = if changed {
                            Duration::from_secs_f64(
                                (dt - last_start.elapsed().as_secs_f64()).max(0.0),
                            )
                        } else {
                            Duration::from_millis(50)
                        };
                        inputs = self
                            .inputs_changed
                            .wait_timeout(inputs, wait)
                            .expect("inputs lock")
                            .0;
                    }
                }
                if inputs.reset {
                    inputs.reset = false;
                    drop(inputs);
                    deformer.reset();
                    for (i, h) in paper_history.iter_mut().enumerate() {
                        *h = self.model.new_history(i);
                    }
                    let prev = self.snapshot();
                    let mut rest = self.model.rest_snapshot(&self.scene);
                    rest.surface_bvh = bvhs.as_mut().map(|b| b.fit(&rest.surface));
                    rest.frame = prev.frame + 1;
                    rest.sim_time_s = prev.sim_time_s;
                    Arc::make_mut(&mut rest.frame_summary).frame = rest.frame;
                    Arc::make_mut(&mut rest.frame_summary).sim_time_s = rest.sim_time_s;
                    self.publish(rest);
                    continue;
                }
                k += 1;
                sim_time = if self.stepped {
                    k as f64 * dt
                } else {
                    self.started.elapsed().as_secs_f64()
                };
                for i in 0..n {
                    let slot = &mut inputs.per_instrument[i];
                    seen_versions[i] = slot.version;
                    let chosen = if self.stepped {
                        // Latest logged pose with t <= t_k; drop older ones.
                        while slot.log.len() >= 2 && slot.log[1].0.t_s <= sim_time {
                            slot.log.pop_front();
                        }
                        match (slot.log.front(), slot.ended_at) {
                            (Some(_), Some(end)) if sim_time > end => None,
                            (Some((p, h)), _) if p.t_s <= sim_time => Some((p.pose, h.clone())),
                            _ => None,
                        }
                    } else if slot.claimed {
                        slot.latest.as_ref().map(|(p, h)| (p.pose, h.clone()))
                    } else {
                        None
                    };
                    match chosen {
                        Some((p, h)) => {
                            poses.push(p);
                            histories.push(Some(h));
                        }
                        None => {
                            poses.push(self.home_pose(i));
                            histories.push(None);
                        }
                    }
                }
            }
            last_start = Instant::now();
            // 2. Collision, FEM, publish.
            let _step_span = tracing::debug_span!("deformation_step", frame = k).entered();
            let prev = self.snapshot();
            let paper_mode = self.scene.collision.history == HistoryMode::Paper;
            let t0 = Instant::now();
            // Force-rate mode: a copy of the force loop's latest history (never
            // written back); paper mode, or an instrument at home: the
            // deformation loop's own history, renewed here.
            let own: Vec<bool> = histories
                .iter()
                .map(|h| paper_mode || h.is_none())
                .collect();
            let mut step_histories: Vec<engine::History> = histories
                .into_iter()
                .enumerate()
                .map(|(i, h)| match h {
                    Some(h) if !paper_mode => h,
                    _ => paper_history[i].clone(),
                })
                .collect();
            let contacts = tracing::debug_span!("collision")
                .in_scope(|| query.query_all(&self.model, &prev, &poses, &mut step_histories));
            for (i, h) in step_histories.into_iter().enumerate() {
                if own[i] {
                    paper_history[i] = h;
                }
            }
            let collision_us = t0.elapsed().as_secs_f64() * 1e6;
            let t1 = Instant::now();
            let result = tracing::debug_span!("solve").in_scope(|| deformer.step(contacts));
            let solve_us = t1.elapsed().as_secs_f64() * 1e6;
            let total_us = last_start.elapsed().as_secs_f64() * 1e6;
            self.step_latency.record(total_us);
            let timings = StepTimings {
                collision_us,
                solve_us,
                total_us,
            };
            let snap = match result {
                Ok(step) => {
                    let mut snap = self.model.snapshot_from(
                        &self.scene,
                        k,
                        sim_time,
                        step,
                        contacts,
                        &poses,
                        paper_history.clone(),
                        timings,
                    );
                    snap.surface_bvh = tracing::debug_span!("refit")
                        .in_scope(|| bvhs.as_mut().map(|b| b.fit(&snap.surface)));
                    snap
                }
                Err(e) => {
                    self.failed_steps.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(frame = k, error = %e, "deformation step failed; keeping the last good state");
                    let mut frame = (*prev.frame_summary).clone();
                    frame.frame = k;
                    frame.sim_time_s = sim_time;
                    frame.timings = timings;
                    frame.solver_error = Some(e.to_string());
                    Snapshot {
                        frame: k,
                        sim_time_s: sim_time,
                        published: Instant::now(),
                        surface: prev.surface.clone(),
                        surface_bvh: prev.surface_bvh.clone(),
                        force_model: prev.force_model.clone(),
                        paper_history: prev.paper_history.clone(),
                        solver_error: Some(e.to_string()),
                        frame_summary: Arc::new(frame),
                    }
                }
            };
            self.publish(snap);
        }
    }
}

/// The last stepped-mode step strictly before time `t` (s): the largest `k >= 0`
/// with `k * dt < t`, or 0. Computed with the same products `k as f64 * dt`
/// as the deformation loop's step times, so both sides agree to the bit.
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

impl Drop for Simulation {
    fn drop(&mut self) {
        self.shutdown.store(true, Ordering::SeqCst);
        self.inputs_changed.notify_all();
    }
}

/// A watcher's frame receiver; the watcher count drops with it.
#[derive(Debug)]
pub struct WatcherGuard {
    sim: Arc<Simulation>,
    /// Frames, latest-wins.
    pub rx: tokio::sync::watch::Receiver<Arc<Frame>>,
}

impl Drop for WatcherGuard {
    fn drop(&mut self) {
        self.sim.watchers.fetch_sub(1, Ordering::SeqCst);
    }
}

/// An exclusive claim of one instrument: its force loop. Released on drop.
pub struct Claim {
    sim: Arc<Simulation>,
    index: usize,
    name: String,
    last: Option<TimedPose>,
    history: engine::History,
    query: ContactQuery,
    ws: ForceWorkspace,
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

    /// Answers one pose: validates it (a rejected pose changes nothing), runs a
    /// collision query against the latest surface and extrapolates the reactions
    /// with the local model. Blocking in stepped mode (it waits for the frame the
    /// pose's time needs); never blocking otherwise.
    pub fn force_sample(&mut self, raw: &RawPose) -> Result<ForceOut, PoseError> {
        let _span = tracing::trace_span!("force_sample", instrument = %self.name).entered();
        // Compute time excludes the stepped-mode wait for the frame.
        let mut t_start = Instant::now();
        let sim = self.sim.clone();
        let pose = match pose::validate(raw, self.last.as_ref()) {
            Ok(p) => p,
            Err(e) => {
                sim.rejected.fetch_add(1, Ordering::Relaxed);
                return Err(e);
            }
        };
        let mut flags = 0;
        if let Some(last) = &self.last {
            let jump = (pose.pose.translation.vector - last.pose.translation.vector).norm();
            if jump > sim.scene.loops.max_jump_m {
                flags |= flags::POSE_JUMP;
            }
        }
        let dt = sim.scene.loops.deformation_interval_s;
        let snap = if sim.stepped {
            {
                let mut inputs = sim.inputs.lock().expect("inputs lock");
                inputs.per_instrument[self.index].reached_t = pose.t_s;
            }
            sim.inputs_changed.notify_all();
            let before_wait = t_start.elapsed();
            let snap = sim.wait_for_frame(step_before(pose.t_s, dt));
            t_start = Instant::now() - before_wait;
            snap
        } else {
            sim.snapshot()
        };
        let paper_mode = sim.scene.collision.history == HistoryMode::Paper;
        if paper_mode {
            self.history.copy_from(&snap.paper_history[self.index]);
        }
        let contact =
            self.query
                .query(&sim.model, &snap, self.index, &pose.pose, &mut self.history);
        let handle = pose.pose.translation.vector;
        let index = self.index as u16;
        let fm = &snap.force_model;
        let f = fm.instrument_force(
            index,
            |node| contact.displacement_of(node),
            &handle,
            &mut self.ws,
        );
        let mut force = f.force;
        let magnitude = force.norm();
        if magnitude > sim.scene.loops.safe_force_n {
            flags |= flags::FORCE_ABOVE_THRESHOLD;
        }
        if magnitude > sim.scene.loops.max_force_n {
            force *= sim.scene.loops.max_force_n / magnitude;
            flags |= flags::FORCE_CLAMPED;
        }
        if snap.solver_error.is_some() {
            flags |= flags::SOLVER_FAILED;
        }
        let model_age_s = if sim.stepped {
            pose.t_s - snap.sim_time_s
        } else {
            snap.published.elapsed().as_secs_f64()
        };
        if model_age_s > 10.0 * dt {
            flags |= flags::MODEL_STALE;
        }
        let contact_count = contact.contact_count();
        {
            let mut inputs = sim.inputs.lock().expect("inputs lock");
            let slot = &mut inputs.per_instrument[self.index];
            slot.version += 1;
            if sim.stepped {
                slot.log.push_back((pose, self.history.clone()));
            } else if let Some((p, h)) = slot.latest.as_mut() {
                // Reuse the slot's flags (no allocation per sample).
                *p = pose;
                h.copy_from(&self.history);
            } else {
                slot.latest = Some((pose, self.history.clone()));
            }
        }
        sim.inputs_changed.notify_all();
        self.last = Some(pose);
        let compute_us = t_start.elapsed().as_secs_f64() * 1e6;
        sim.force_latency.record(compute_us);
        sim.force_samples.fetch_add(1, Ordering::Relaxed);
        Ok(ForceOut {
            sequence: pose.sequence,
            t_s: pose.t_s,
            force_n: force,
            torque_nm: f.torque,
            contact_count,
            model_frame: snap.frame,
            model_age_s,
            safety_flags: flags,
            compute_us,
        })
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        {
            let mut inputs = self.sim.inputs.lock().expect("inputs lock");
            let slot = &mut inputs.per_instrument[self.index];
            slot.claimed = false;
            slot.latest = None;
            slot.version += 1;
            slot.ended_at = Some(self.last.map_or(f64::NEG_INFINITY, |p| p.t_s));
        }
        self.sim.inputs_changed.notify_all();
        tracing::info!(instrument = %self.name, "instrument released");
    }
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
