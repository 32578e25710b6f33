//! The force loop and the deformation loop, their shared state and recording
//! (DESIGN.md section 4).
//!
//! * The **deformation loop** ([`engine::StepEngine`]) runs on its own
//!   thread: latest poses -> collision with culling for every instrument ->
//!   the contact rows -> the contact problem's solve -> a [`Snapshot`]
//!   swapped in atomically (latest wins) and a [`Frame`] sent on a `watch`
//!   channel (slow watchers see only the latest frame). The snapshot carries
//!   the compliance patch the force loops solve on and, with the CPU BVH, the
//!   tree refitted to its surface, which every force loop casts on
//!   read-only. The thread and its rayon pool run at a lower priority
//!   ([`priority`], [`SimOptions::deformation_nice`]) so that force samples
//!   preempt the solver; compliance it lacks is computed on a background
//!   thread lower still (contacts on such vertices are answered by a
//!   penalty and flagged meanwhile), so no step waits for it.
//! * The **force loop** of a claimed instrument ([`Claim::force_sample`],
//!   [`force_loop`]) runs in the caller's thread: a fresh collision query
//!   (sequential, on the snapshot's tree) against the latest snapshot's
//!   surface, the instrument's rows, and the contact problem coupled with
//!   the other instruments' latest rows, on the compliance of the last
//!   step. It never waits for the deformation loop.
//! * **Stepped mode** ([`stepped`]) makes runs reproducible: one thread runs
//!   a [`stepped::SteppedRunner`], which answers the poses of each time
//!   together once every claimed instrument has sent its next pose (and at
//!   least the [`Mode::Stepped`] clients have been claimed): deformation
//!   step `k` happens at `t_k = t_0 + k dt` (`t_0` the session's first pose
//!   time) with, per instrument, the latest pose with `t <= t_k`; a force
//!   sample at pose time `t` uses the last step strictly before `t`. Columns
//!   of the compliance are computed when a step needs them (the answers do
//!   not depend on timing). `fissure study` drives the same runner.

pub mod budget;
pub mod engine;
pub mod force_loop;
pub mod haptic_stream;
pub mod injury;
pub mod journal;
pub mod local_model;
pub mod motion;
pub mod pose;
pub mod priority;
pub mod rows;
pub mod snapshot;
pub mod stats;
pub mod stepped;

pub use stepped::step_before;

use crate::fem::compliance::ColumnPolicy;
use crate::scene::Scene;
use engine::{Model, StepEngine};
use force_loop::{ForceLoop, SampleForce};
use nalgebra::{Isometry3, Vector3};
use pose::{PoseError, RawPose, TimedPose};
use rows::Row;
use snapshot::{Frame, Snapshot};
use stats::{LatencyRecorder, StatsSummary};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use stepped::{StepDone, SteppedRunner};

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
    /// A vertex the instrument touches has no compliance yet: its force is
    /// a penalty estimate until its columns are computed.
    pub const COLUMNS_PENDING: u32 = 32;
    /// The sample's contact problem was not solved: the last good force is
    /// repeated.
    pub const CONTACT_UNSOLVED: u32 = 64;
    /// The instrument tore a bridging vessel (sticky until a reset).
    pub const VESSEL_TORN: u32 = 128;
}

/// How a simulation's loops advance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Each instrument's force loop answers its poses as they come, on its
    /// own thread; the deformation loop steps whenever a pose changed and
    /// the interval has passed (real time).
    FreeRunning,
    /// Reproducible: one thread answers the poses of each time step in
    /// order and runs the steps at their simulation times
    /// ([`stepped::SteppedRunner`]). The first step waits until `clients`
    /// instruments have been claimed, so that runs with several clients
    /// are reproducible whatever order they connect in.
    Stepped {
        /// Instruments claimed before the first step (at least 1).
        clients: usize,
    },
}

impl Mode {
    /// Whether this is [`Mode::Stepped`].
    pub fn is_stepped(self) -> bool {
        matches!(self, Mode::Stepped { .. })
    }

    /// The scene's own mode (`[loops] stepped`), with one client.
    pub fn of(scene: &Scene) -> Self {
        if scene.loops.stepped {
            Mode::Stepped { clients: 1 }
        } else {
            Mode::FreeRunning
        }
    }
}

/// Options of a simulation beyond the scene file.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Override of the scene's mode (`None`: [`Mode::of`] the scene).
    pub mode: Option<Mode>,
    /// Where the session is recorded, if anywhere: opened once the model is
    /// built ([`journal`]).
    pub recording: Option<Arc<dyn journal::OpenJournal>>,
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
            mode: None,
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
    /// The scene asks for a part this build lacks.
    #[error("building the model: {0}")]
    Scene(#[from] crate::scene::SceneError),
    /// The phantom preset could not be generated.
    #[error("building the model: {0}")]
    Phantom(#[from] crate::mesh::phantom::PhantomError),
    /// The model file could not be read.
    #[error("building the model: {0}")]
    ModelFile(#[from] crate::mesh::io::ModelFileError),
    /// An instrument of the scene could not be built.
    #[error("building the model: instrument {name:?}: {source}")]
    Instrument {
        name: String,
        source: crate::collide::tool::instrument::InstrumentError,
    },
    /// A fixed region names a landmark the model does not have.
    #[error(
        "building the model: the model has no landmark named {landmark:?} (the phantom has \"brain-stem\")"
    )]
    UnknownLandmark { landmark: String },
    /// The region of interest could not be cropped.
    #[error("building the model: region of interest: {0}")]
    RegionOfInterest(#[source] crate::fem::SolveError),
    /// No node lies in the fixed regions.
    #[error("building the model: no node lies in the fixed region(s); the model would float")]
    Floating,
    /// The elastic foundation's regions could not be resolved.
    #[error("building the model: {0}")]
    Foundation(#[from] crate::scene::region::RegionError),
    /// The scene's ties could not be placed.
    #[error("building the model: {0}")]
    Ties(#[from] crate::scene::ties::TieError),
    /// The solver could not be set up.
    #[error("setting up the solver: {0}")]
    Solver(#[source] crate::fem::SolveError),
    /// The recording could not be opened.
    #[error("opening the recording {path}: {source}")]
    Recording {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The loop thread could not be started.
    #[error("cannot start the loop thread: {0}")]
    Thread(#[source] std::io::Error),
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

/// A pose waiting for the stepped runner, and where its answer goes.
struct Pending {
    pose: TimedPose,
    reply: Arc<Reply>,
}

/// A claim's answer slot (reused from one pose to the next).
#[derive(Default)]
struct Reply {
    slot: Mutex<Option<Result<ForceOut, PoseError>>>,
    ready: Condvar,
}

impl Reply {
    fn send(&self, r: Result<ForceOut, PoseError>) {
        *self.slot.lock().expect("reply lock") = Some(r);
        self.ready.notify_all();
    }
}

/// Per-instrument input state shared between its force loop and the loops.
#[derive(Default)]
struct InstrumentInput {
    claimed: bool,
    /// Ever claimed ([`Mode::Stepped`] counts these).
    ever_claimed: bool,
    /// Free-running: the latest accepted pose and the force-rate history
    /// after it.
    latest: Option<(TimedPose, engine::History)>,
    /// Bumped at each accepted pose (free-running: has anything changed?).
    version: u64,
    /// Stepped: poses waiting for the runner, oldest first.
    queue: VecDeque<Pending>,
    /// Stepped: the claim's stream ended and the runner has not been told.
    ended: bool,
}

struct Inputs {
    per_instrument: Vec<InstrumentInput>,
    reset: bool,
}

/// An instrument's latest rows, for the other force loops (free-running).
#[derive(Default)]
struct SharedRows {
    live: bool,
    rows: Arc<Vec<Row>>,
}

/// A running simulation: the model, the loop thread, the shared state.
pub struct Simulation {
    scene: Scene,
    model: Arc<Model>,
    mode: Mode,
    options: SimOptions,
    snapshot: RwLock<Arc<Snapshot>>,
    frames: tokio::sync::watch::Sender<Arc<Frame>>,
    inputs: Mutex<Inputs>,
    inputs_changed: Condvar,
    /// Resets done so far, and the frame of the last.
    resets: Mutex<(u64, u64)>,
    reset_done: Condvar,
    shutdown: AtomicBool,
    thread: Mutex<Option<JoinHandle<()>>>,
    started: Instant,
    force_latency: LatencyRecorder,
    /// The collision query of free-running force samples.
    force_collision_latency: LatencyRecorder,
    step_latency: LatencyRecorder,
    force_samples: AtomicU64,
    rejected: AtomicU64,
    failed_steps: AtomicU64,
    solver_cache_bytes: AtomicU64,
    watchers: AtomicU64,
    recorder: Option<Arc<dyn journal::Journal>>,
    shared_rows: Vec<Mutex<SharedRows>>,
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("scene", &self.scene.name)
            .finish_non_exhaustive()
    }
}

/// Nice value of the background column thread above the deformation
/// loop's.
const COLUMN_WORKER_NICE_ABOVE: i32 = 5;

/// How long [`Simulation::reset`] waits for the rest frame.
const RESET_WAIT: Duration = Duration::from_secs(10);

impl Simulation {
    /// Builds the model and the solver, publishes the rest state as frame 0 and
    /// starts the loop thread.
    pub fn start(mut scene: Scene, options: SimOptions) -> Result<Arc<Self>, SimError> {
        let loading = Instant::now();
        crate::progress::stage(format_args!("scene {}: building the model", scene.name));
        let model = Arc::new(Model::build(&scene)?);
        let mode = options.mode.unwrap_or_else(|| Mode::of(&scene));
        let stepped = mode.is_stepped();
        // The scene as run: GetScene and the recording header report the
        // effective mode, not the file's.
        scene.loops.stepped = stepped;
        let nice = options.deformation_nice;
        let hook: Arc<dyn Fn() + Send + Sync> =
            Arc::new(move || priority::lower_current_thread(nice + COLUMN_WORKER_NICE_ABOVE));
        let columns = if stepped {
            ColumnPolicy::Compute
        } else {
            ColumnPolicy::Defer
        };
        crate::progress::stage(format_args!(
            "scene {}: setting up the {} solver ({} nodes, {} tetrahedra)",
            scene.name,
            scene.solver.strategy.name(),
            model.mesh.nodes.len(),
            model.mesh.tets.len()
        ));
        let mut engine = StepEngine::new(&scene, model.clone(), columns, Some(hook), None)?;
        let recorder = match &options.recording {
            Some(open) => {
                Some(
                    open.open(&scene, &model)
                        .map_err(|source| SimError::Recording {
                            path: open.path().to_owned(),
                            source,
                        })?,
                )
            }
            None => None,
        };
        let n = scene.instruments.len();
        enum Runner {
            Stepped(Box<SteppedRunner>),
            Free(Box<StepEngine>),
        }
        let (runner, rest) = if stepped {
            let loops = (0..n)
                .map(|i| ForceLoop::new(&scene, &model, i, None))
                .collect();
            let r = SteppedRunner::new(&scene, engine, loops);
            let rest = r.snapshot().clone();
            (Runner::Stepped(Box::new(r)), rest)
        } else {
            let rest = Arc::new(engine.rest(0.0));
            (Runner::Free(Box::new(engine)), rest)
        };
        let (frames, _) = tokio::sync::watch::channel(rest.frame_summary.clone());
        let sim = Arc::new(Self {
            model: model.clone(),
            mode,
            options,
            snapshot: RwLock::new(rest.clone()),
            frames,
            inputs: Mutex::new(Inputs {
                per_instrument: (0..n).map(|_| InstrumentInput::default()).collect(),
                reset: false,
            }),
            inputs_changed: Condvar::new(),
            resets: Mutex::new((0, 0)),
            reset_done: Condvar::new(),
            shutdown: AtomicBool::new(false),
            thread: Mutex::new(None),
            started: Instant::now(),
            force_latency: LatencyRecorder::default(),
            force_collision_latency: LatencyRecorder::default(),
            step_latency: LatencyRecorder::default(),
            force_samples: AtomicU64::new(0),
            rejected: AtomicU64::new(0),
            failed_steps: AtomicU64::new(0),
            solver_cache_bytes: AtomicU64::new(0),
            watchers: AtomicU64::new(0),
            recorder,
            shared_rows: (0..n).map(|_| Mutex::new(SharedRows::default())).collect(),
            scene,
        });
        if let Some(rec) = &sim.recorder {
            rec.frame(&rest.frame_summary);
        }
        let worker = sim.clone();
        let handle = std::thread::Builder::new()
            .name(
                if stepped {
                    "stepped-loop"
                } else {
                    "deformation-loop"
                }
                .into(),
            )
            .spawn(move || {
                let nice = worker.options.deformation_nice;
                priority::lower_current_thread(nice);
                let run = move || match runner {
                    Runner::Stepped(r) => worker.stepped_loop(*r),
                    Runner::Free(e) => worker.deformation_loop(*e),
                };
                match priority::deformation_pool(nice) {
                    Some(pool) => pool.install(run),
                    None => run(),
                }
            })
            .map_err(SimError::Thread)?;
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

    /// How the loops advance (the options' mode, else the scene's).
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether deformation steps follow pose timestamps
    /// ([`Mode::Stepped`]).
    pub fn is_stepped(&self) -> bool {
        self.mode.is_stepped()
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
            slot.ended = false;
            slot.queue.clear();
        }
        self.inputs_changed.notify_all();
        tracing::info!(instrument = name, "instrument claimed");
        Ok(Claim {
            sim: self.clone(),
            index,
            name: name.to_owned(),
            last: None,
            resets_seen: self.resets.lock().expect("resets lock").0,
            force_loop: (!self.is_stepped())
                .then(|| ForceLoop::new(&self.scene, &self.model, index, None)),
            held: Vec::new(),
            reply: Arc::new(Reply::default()),
        })
    }

    /// Returns the tissue to rest, clears the histories and restarts the
    /// stepped clock; waits (up to 10 s) for the rest frame and returns its
    /// number.
    pub fn reset(&self) -> u64 {
        let before = self.resets.lock().expect("resets lock").0;
        {
            let mut inputs = self.inputs.lock().expect("inputs lock");
            inputs.reset = true;
        }
        self.inputs_changed.notify_all();
        let deadline = Instant::now() + RESET_WAIT;
        let mut resets = self.resets.lock().expect("resets lock");
        while resets.0 == before && !self.shutdown.load(Ordering::SeqCst) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            resets = self
                .reset_done
                .wait_timeout(resets, left)
                .expect("resets lock")
                .0;
        }
        if resets.0 == before {
            self.snapshot().frame + 1
        } else {
            resets.1
        }
    }

    /// Counters and latency percentiles.
    pub fn stats(&self) -> StatsSummary {
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
            force_collision: self.force_collision_latency.summary(),
            deformation_step: self.step_latency.summary(),
            failed_steps: self.failed_steps.load(Ordering::Relaxed),
            solver_cache_bytes: self.solver_cache_bytes.load(Ordering::Relaxed),
            recording_lost: self.recorder().map_or(0, |r| r.lost()),
        }
    }

    /// Stops the loop thread, flushes the recording, releases waiters.
    pub fn shutdown(&self) {
        self.shutdown.store(true, Ordering::SeqCst);
        self.inputs_changed.notify_all();
        self.reset_done.notify_all();
        if let Some(handle) = self.thread.lock().expect("thread lock").take() {
            let _ = handle.join();
        }
        self.fail_pending();
        if let Some(rec) = &self.recorder {
            rec.flush();
        }
    }

    /// Answers every pose still waiting for the stepped runner with a
    /// refusal (the server is stopping).
    fn fail_pending(&self) {
        let mut inputs = self.inputs.lock().expect("inputs lock");
        for slot in &mut inputs.per_instrument {
            for p in slot.queue.drain(..) {
                p.reply.send(Err(PoseError::NotAnswered(
                    "the server is shutting down".into(),
                )));
            }
        }
    }

    /// Counts a pose rejected before it reached a claim (a missing field, a
    /// stream over its rate), in the stats' `rejected_poses`.
    pub fn record_rejection(&self) {
        self.rejected.fetch_add(1, Ordering::Relaxed);
    }

    /// The session's journal, if recording.
    pub fn recorder(&self) -> Option<&dyn journal::Journal> {
        self.recorder.as_deref()
    }

    fn publish(&self, snap: Arc<Snapshot>) {
        let frame = snap.frame_summary.clone();
        *self.snapshot.write().expect("snapshot lock") = snap;
        self.frames.send_replace(frame.clone());
        if let Some(rec) = &self.recorder {
            rec.frame(&frame);
        }
    }

    fn note_step(&self, done: &StepDone) {
        if done.report.is_none() && done.snapshot.solver_error.is_some() {
            self.failed_steps.fetch_add(1, Ordering::Relaxed);
        }
        if let Some(report) = &done.report {
            self.solver_cache_bytes
                .store(report.cache_bytes as u64, Ordering::Relaxed);
        }
        if done.step_us > 0.0 {
            self.step_latency.record(done.step_us);
        }
        self.publish(done.snapshot.clone());
    }

    fn finish_reset(&self, frame: u64) {
        let mut r = self.resets.lock().expect("resets lock");
        r.0 += 1;
        r.1 = frame;
        drop(r);
        self.reset_done.notify_all();
    }

    /// A force sample's answer: the sample with the scene's safety
    /// processing (threshold flag, clamp) and the model's age.
    fn answer(
        &self,
        pose: &TimedPose,
        s: &SampleForce,
        frame: u64,
        model_age_s: f64,
        solver_failed: bool,
        compute_us: f64,
    ) -> ForceOut {
        let loops = &self.scene.loops;
        let mut flags = s.flags;
        let mut force = s.force_n;
        let magnitude = force.norm();
        if magnitude > loops.safe_force_n {
            flags |= flags::FORCE_ABOVE_THRESHOLD;
        }
        if magnitude > loops.max_force_n {
            force *= loops.max_force_n / magnitude;
            flags |= flags::FORCE_CLAMPED;
        }
        if solver_failed {
            flags |= flags::SOLVER_FAILED;
        }
        if model_age_s > 10.0 * loops.deformation_interval_s {
            flags |= flags::MODEL_STALE;
        }
        ForceOut {
            sequence: pose.sequence,
            t_s: pose.t_s,
            force_n: force,
            torque_nm: s.torque_nm,
            contact_count: s.contact_count,
            model_frame: frame,
            model_age_s,
            safety_flags: flags,
            compute_us,
        }
    }

    /// Free-running: a step whenever a pose changed and the interval has
    /// passed.
    fn deformation_loop(self: Arc<Self>, mut engine: StepEngine) {
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
                        .any(|(s, &v)| s.version != v);
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
                    seen_versions[i] = slot.version;
                    match slot.latest.as_ref().filter(|_| slot.claimed) {
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
    fn stepped_loop(self: Arc<Self>, mut runner: SteppedRunner) {
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
                        if slot.ended && slot.queue.is_empty() {
                            slot.ended = false;
                            runner.end(i);
                        }
                    }
                    let ever = inputs
                        .per_instrument
                        .iter()
                        .filter(|s| s.ever_claimed)
                        .count();
                    let claimed = || inputs.per_instrument.iter().filter(|s| s.claimed);
                    let any = claimed().any(|s| !s.queue.is_empty());
                    let all = claimed().all(|s| !s.queue.is_empty());
                    // An ended stream's poses still queued are answered too.
                    let leftover = inputs
                        .per_instrument
                        .iter()
                        .any(|s| !s.claimed && !s.queue.is_empty());
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
                    .filter_map(|s| s.queue.front().map(|p| p.pose.t_s))
                    .fold(f64::INFINITY, f64::min);
                for (i, slot) in inputs.per_instrument.iter_mut().enumerate() {
                    if slot.queue.front().is_some_and(|p| p.pose.t_s == t) {
                        batch.push((i, slot.queue.pop_front().expect("front checked")));
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
    resets_seen: u64,
    /// Free-running: the instrument's force loop (stepped: the runner's).
    force_loop: Option<ForceLoop>,
    /// Free-running: the other instruments' rows read for one sample.
    held: Vec<Option<Arc<Vec<Row>>>>,
    reply: Arc<Reply>,
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
            inputs.per_instrument[self.index].queue.push_back(Pending {
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
        {
            let mut mine = sim.shared_rows[self.index].lock().expect("rows lock");
            mine.live = true;
            match Arc::get_mut(&mut mine.rows) {
                Some(v) => {
                    v.clear();
                    v.extend_from_slice(fl.rows());
                }
                None => mine.rows = Arc::new(fl.rows().to_vec()),
            }
        }
        self.held.clear();
        for (j, slot) in sim.shared_rows.iter().enumerate() {
            if j == self.index {
                self.held.push(None);
                continue;
            }
            let s = slot.lock().expect("rows lock");
            self.held.push(s.live.then(|| s.rows.clone()));
        }
        let held = &self.held;
        let others = |j: usize| held.get(j).and_then(|h| h.as_deref().map(|v| v.as_slice()));
        let sample = fl.solve(&sim.model, &snap, &others, &pose.pose.translation.vector);
        self.held.clear();
        {
            let mut inputs = sim.inputs.lock().expect("inputs lock");
            let slot = &mut inputs.per_instrument[self.index];
            slot.version += 1;
            match slot.latest.as_mut() {
                Some((p, h)) => {
                    // Reuse the slot's flags (no allocation per sample).
                    *p = *pose;
                    h.copy_from(fl.history());
                }
                None => slot.latest = Some((*pose, fl.history().clone())),
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
            slot.latest = None;
            slot.version += 1;
            slot.ended = true;
        }
        {
            let mut mine = self.sim.shared_rows[self.index].lock().expect("rows lock");
            mine.live = false;
        }
        self.sim.inputs_changed.notify_all();
        tracing::info!(instrument = %self.name, "instrument released");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ModelSpec, Region};
    use std::error::Error as _;

    fn cube() -> Scene {
        Scene::load("cube").unwrap().0
    }

    #[test]
    fn a_model_that_cannot_be_built_says_why_in_a_variant_callers_match() {
        let mut floating = cube();
        floating.fixed = vec![Region::Box {
            box_min_m: [1.0, 1.0, 1.0],
            box_max_m: [2.0, 2.0, 2.0],
        }];
        let e = Model::build(&floating).unwrap_err();
        assert!(matches!(e, SimError::Floating), "{e:?}");
        assert_eq!(
            e.to_string(),
            "building the model: no node lies in the fixed region(s); the model would float"
        );

        let mut landmark = cube();
        landmark.fixed = vec![Region::Landmark {
            landmark: "brain-stem".into(),
        }];
        let e = Model::build(&landmark).unwrap_err();
        assert!(
            matches!(&e, SimError::UnknownLandmark { landmark } if landmark == "brain-stem"),
            "{e:?}"
        );
    }

    #[test]
    fn an_unreadable_model_file_keeps_the_reader_error_as_its_source() {
        let mut scene = cube();
        let path = std::env::temp_dir().join("fissure-no-such-model.vtu");
        scene.model = ModelSpec::File {
            path: path.clone(),
            scale: 1.0,
        };
        let e = Model::build(&scene).unwrap_err();
        let SimError::ModelFile(source) = &e else {
            panic!("expected SimError::ModelFile, got {e:?}");
        };
        let text = e.to_string();
        assert!(text.starts_with("building the model: "), "{text}");
        assert!(text.contains(&source.to_string()), "{text}");
        assert!(e.source().is_some(), "the reader's error is the source");
    }
}
