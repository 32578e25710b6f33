//! The runtime of a simulation: the [`Simulation`] that owns the model and
//! the shared state, starts the deformation loop's thread
//! ([`driver`]: free-running or stepped), hands out the instruments'
//! [`Claim`]s, and keeps the counters ([`stats`]), the pose budget
//! ([`budget`]), the journal ([`journal`]) and the loops' priorities
//! ([`priority`]). What the loops compute lives in [`super::core`].

pub mod budget;
mod claim;
mod driver;
pub mod haptic_stream;
pub mod journal;
pub mod priority;
pub mod stats;

pub use claim::Claim;

use super::core::engine::ModelError;
pub use super::core::flags;
use super::core::{engine, force_loop, pose, snapshot, stepped};
use crate::fem::compliance::ColumnPolicy;
use crate::scene::Scene;
use engine::{Model, StepEngine};
use force_loop::{ForceLoop, HeldRows, RowExchange, SampleForce};
use nalgebra::Vector3;
use pose::{PoseError, TimedPose};
use snapshot::{Frame, Snapshot};
use stats::{LatencyRecorder, StatsSummary};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use stepped::{StepDone, SteppedRunner};

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
    /// The model could not be built.
    #[error(transparent)]
    Model(#[from] ModelError),
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
struct InstrumentInput {
    claimed: bool,
    /// Ever claimed ([`Mode::Stepped`] counts these).
    ever_claimed: bool,
    /// How its poses reach the deformation loop: one lane per [`Mode`].
    lane: Lane,
}

/// How an instrument's poses reach the deformation loop.
enum Lane {
    /// [`Mode::FreeRunning`]: the loop steps on the newest pose.
    Latest(Latest),
    /// [`Mode::Stepped`]: the runner answers every pose, in order.
    Queued(Queued),
}

/// A free-running instrument's newest pose.
#[derive(Default)]
struct Latest {
    /// The latest accepted pose and the force-rate history after it.
    pose: Option<(TimedPose, engine::History)>,
    /// Bumped at each accepted pose and at release (has anything changed?).
    version: u64,
}

/// A stepped instrument's poses waiting for the runner.
#[derive(Default)]
struct Queued {
    /// Oldest first.
    poses: VecDeque<Pending>,
    /// The claim's stream ended and the runner has not been told.
    ended: bool,
}

impl InstrumentInput {
    fn new(mode: Mode) -> Self {
        Self {
            claimed: false,
            ever_claimed: false,
            lane: match mode {
                Mode::FreeRunning => Lane::Latest(Latest::default()),
                Mode::Stepped { .. } => Lane::Queued(Queued::default()),
            },
        }
    }

    /// The free-running lane (a simulation's mode never changes, so the
    /// free-running paths only ever meet this one).
    fn latest(&self) -> &Latest {
        match &self.lane {
            Lane::Latest(l) => l,
            Lane::Queued(_) => unreachable!("a stepped simulation has no latest pose"),
        }
    }

    fn latest_mut(&mut self) -> &mut Latest {
        match &mut self.lane {
            Lane::Latest(l) => l,
            Lane::Queued(_) => unreachable!("a stepped simulation has no latest pose"),
        }
    }

    /// The stepped lane.
    fn queued(&self) -> &Queued {
        match &self.lane {
            Lane::Queued(q) => q,
            Lane::Latest(_) => unreachable!("a free-running simulation queues no pose"),
        }
    }

    fn queued_mut(&mut self) -> &mut Queued {
        match &mut self.lane {
            Lane::Queued(q) => q,
            Lane::Latest(_) => unreachable!("a free-running simulation queues no pose"),
        }
    }
}

struct Inputs {
    per_instrument: Vec<InstrumentInput>,
    reset: bool,
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
    /// The free-running force loops' rows, each read by the others.
    exchange: RowExchange,
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
                per_instrument: (0..n).map(|_| InstrumentInput::new(mode)).collect(),
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
            exchange: RowExchange::new(n),
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
            if let Lane::Queued(q) = &mut slot.lane {
                q.ended = false;
                q.poses.clear();
            }
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
            held: HeldRows::default(),
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
            let Lane::Queued(q) = &mut slot.lane else {
                continue;
            };
            for p in q.poses.drain(..) {
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
        assert!(matches!(e, ModelError::Floating), "{e:?}");
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
            matches!(&e, ModelError::UnknownLandmark { landmark } if landmark == "brain-stem"),
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
        let ModelError::ModelFile(source) = &e else {
            panic!("expected ModelError::ModelFile, got {e:?}");
        };
        let text = e.to_string();
        assert!(text.starts_with("building the model: "), "{text}");
        assert!(text.contains(&source.to_string()), "{text}");
        assert!(e.source().is_some(), "the reader's error is the source");
    }
}
