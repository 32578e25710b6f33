//! `fissure bench loop`: the force loop under its intended load. An in-process
//! server (free-running) on a scene, every instrument driven by a haptic client
//! at the haptic rate, each pose sent on its own tick of the wall clock, and a
//! number of watchers receiving full deformation frames.
//!
//! The server runs as `fissure-server` runs it, on a transport runtime of its
//! own ([`Transport`]). Each client is a device bridge of its own, as a
//! separate process would be: a connection thread with a single-threaded
//! runtime (its I/O never queues behind the server's or the watchers') and a
//! servo thread, both real-time where permitted (`--rt-priority`).
//!
//! A client's pose `k` is due at `start + k / rate`; it is sent at its tick
//! whether or not earlier answers came back (as a haptic device's servo loop
//! does). Its answer is *missed* when it arrives after tick `k + 1` is due, or
//! never. Round trips are measured from the actual send instant; the server's
//! compute time is the one it reports in each sample.
//!
//! The poses follow the scene's bundled trajectories, played forwards and
//! backwards (ping-pong) for as long as the run lasts, with pose times on the
//! ticks (so contact and a changing surface persist for the whole run).

use crate::client::replay::{connect, haptic_request};
use crate::client::trajectory::{BUNDLED, Trajectory, Waypoint};
use anyhow::{Context, bail};
use fissure_engine::scene::{Scene, Traversal};
use fissure_engine::sim::runtime::priority;
use fissure_engine::sim::runtime::stats::percentile;
use fissure_engine::sim::{Mode, SimOptions, Simulation};
use fissure_proto::v1 as pb;
use fissure_server::{ServeOptions, Transport};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Options of `fissure bench loop`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoopBenchArgs {
    /// Scene (an embedded name with bundled trajectories).
    #[arg(long, default_value = fissure_engine::scene::DEFAULT_SCENE)]
    pub scene: String,
    /// Length of the timed run, s.
    #[arg(long, default_value_t = 10.0)]
    pub duration_s: f64,
    /// Watchers receiving full frames (positions included).
    #[arg(long, default_value_t = 4)]
    pub watchers: usize,
    /// Haptic rate of each client, Hz.
    #[arg(long, default_value_t = 1000.0)]
    pub rate_hz: f64,
    /// Real-time priority (SCHED_FIFO, 1-99) of the server's force loops and
    /// of the clients' pose threads (a haptic device's servo loop is
    /// real-time); 0 asks for none. Where it is not permitted, both run at
    /// normal priority and the report says so.
    #[arg(long, default_value_t = fissure_engine::sim::runtime::priority::DEFAULT_FORCE_LOOP_RT_PRIORITY,
          value_parser = clap::value_parser!(u8).range(0..=99))]
    pub rt_priority: u8,
    /// Real-time priority (SCHED_FIFO, 1-99) of the server's gRPC transport
    /// threads (`fissure-server --transport-rt-priority`); 0 asks for none.
    #[arg(long, default_value_t = fissure_engine::sim::runtime::priority::DEFAULT_TRANSPORT_RT_PRIORITY,
          value_parser = clap::value_parser!(u8).range(0..=99))]
    pub transport_rt_priority: u8,
    /// How the CPU BVH walks each face's parallel rays (the scene's
    /// `collision.traversal` unless given): `bundled` or `per-ray`.
    #[arg(long, value_parser = parse_traversal)]
    pub traversal: Option<Traversal>,
    /// Also run this scene (an embedded name or a scene file with bundled
    /// trajectories) as the baseline, alternating with `--scene` run for run
    /// (baseline first), and print the ratios of `--scene` over it: each
    /// round's pair of runs gives a ratio (a change in the machine's load
    /// falls on both), and the median over the rounds is reported.
    #[arg(long)]
    pub baseline_scene: Option<String>,
    /// Rounds of the paired runs with `--baseline-scene` (each round runs
    /// both scenes for `--duration-s`).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub rounds: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// A traversal by the name a scene file gives it.
fn parse_traversal(s: &str) -> Result<Traversal, String> {
    const ALL: [Traversal; 2] = [Traversal::Bundled, Traversal::PerRay];
    ALL.into_iter().find(|t| t.name() == s).ok_or_else(|| {
        let names: Vec<String> = ALL.iter().map(|t| format!("{:?}", t.name())).collect();
        format!("{s:?}: expected {}", names.join(" or "))
    })
}

impl Default for LoopBenchArgs {
    fn default() -> Self {
        Self {
            scene: fissure_engine::scene::DEFAULT_SCENE.to_owned(),
            duration_s: 10.0,
            watchers: 4,
            rate_hz: 1000.0,
            rt_priority: fissure_engine::sim::runtime::priority::DEFAULT_FORCE_LOOP_RT_PRIORITY,
            transport_rt_priority:
                fissure_engine::sim::runtime::priority::DEFAULT_TRANSPORT_RT_PRIORITY,
            traversal: None,
            baseline_scene: None,
            rounds: 3,
            json: false,
        }
    }
}

/// What one run measured. Times in microseconds unless the name says otherwise.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LoopBenchReport {
    /// Scene name.
    pub scene: String,
    /// Surface triangles of the model.
    pub surface_triangles: usize,
    /// Time to build the model and the solver, s.
    pub load_s: f64,
    /// How the CPU BVH walked runs of parallel rays ("bundled", "per-ray").
    pub traversal: String,
    /// Timed run, s.
    pub duration_s: f64,
    /// Haptic rate per client, Hz.
    pub rate_hz: f64,
    /// Haptic clients (one per instrument).
    pub clients: usize,
    /// Watchers.
    pub watchers: usize,
    /// Whether the force loops and the clients' pose threads ran under
    /// `SCHED_FIFO` (`--rt-priority`, where permitted).
    pub realtime: bool,
    /// Whether the server's gRPC transport threads ran under `SCHED_FIFO`
    /// (`--transport-rt-priority`, where permitted).
    pub transport_realtime: bool,
    /// Poses sent, all clients.
    pub samples_sent: u64,
    /// Force samples received.
    pub samples_answered: u64,
    /// Of those, the ones flagged `SAFETY_FLAG_COLUMNS_PENDING`: a vertex
    /// the instrument touched had no compliance computed yet, and its part
    /// of the force was a penalty estimate (first contact before the
    /// background columns arrive).
    pub samples_pending: u64,
    /// Samples whose answer came after the next tick was due, or never.
    pub missed_samples: u64,
    /// Of those, the ones whose round trip alone was longer than a tick
    /// period, or that were never answered; the others left the client late
    /// (the client machine's scheduling, `send_lag_p99_us`).
    pub missed_by_round_trip: u64,
    /// Of the missed samples, those during which no stall probe saw the
    /// machine stall: the ones the server and the clients are answerable for.
    /// An upper bound: a probe samples its CPU once a period, so a stall that
    /// starts and ends between two of its wake-ups goes unseen.
    pub missed_outside_stalls: u64,
    /// Stalls of the machine: wake-ups of the stall probes (one thread pinned
    /// to each CPU, real-time above the server's and the clients' threads
    /// ([`STALL_PROBE_RT_PRIORITY`]), sleeping to the same ticks and doing
    /// nothing else) later than [`STALL_THRESHOLD_US`].
    pub machine_stalls: u64,
    /// The latest such wake-up.
    pub machine_stall_max_us: f64,
    /// CPUs that had a stall probe.
    pub stall_probe_cpus: usize,
    /// Round trip, client side: median, 99th percentile, maximum.
    pub rtt_p50_us: f64,
    pub rtt_p99_us: f64,
    pub rtt_max_us: f64,
    /// Server-side force computation (as reported per sample).
    pub server_force_p50_us: f64,
    pub server_force_p99_us: f64,
    pub server_force_max_us: f64,
    /// Of that, the collision query of the sample's instrument (the
    /// server's own record, over its last 65,536 samples).
    pub force_collision_p50_us: f64,
    pub force_collision_p99_us: f64,
    pub force_collision_max_us: f64,
    /// How late poses left the client after their tick (scheduling of the
    /// client machine), 99th percentile.
    pub send_lag_p99_us: f64,
    /// Deformation frames published per second during the run.
    pub deform_hz: f64,
    /// Deformation step time: median and 99th percentile, ms.
    pub deform_step_p50_ms: f64,
    pub deform_step_p99_ms: f64,
    /// Frames published during the run.
    pub frames_published: u64,
    /// Frames received, all watchers together.
    pub frames_delivered: u64,
    /// Frames received by the slowest watcher.
    pub frames_delivered_min: u64,
    /// Largest age of the deformation model behind a force sample, ms.
    pub model_age_max_ms: f64,
    /// Largest contact count of a sample.
    pub contact_count_max: u32,
    /// Deformation steps that failed during the run.
    pub failed_steps: u64,
}

/// One answer as the client saw it.
#[derive(Debug, Clone, Copy)]
struct Answer {
    sequence: u64,
    arrived: Instant,
    server_us: f64,
    model_age_s: f64,
    contact_count: u32,
    /// Flagged COLUMNS_PENDING: part of the force is a penalty estimate.
    pending: bool,
    rejected: bool,
}

/// A probe's wake-up later than this counts as a stall of the machine, us:
/// on an idle machine a real-time sleep loop wakes within tens of
/// microseconds, and a stall this long, added to a round trip of a few
/// hundred, can make a sample miss its tick.
pub const STALL_THRESHOLD_US: f64 = 250.0;

/// Real-time priority of the stall probes when the run asks for real-time
/// threads: above every thread of the server and the clients, so that only
/// the machine (the hypervisor, the kernel) can delay a probe, never the
/// server's own work.
pub const STALL_PROBE_RT_PRIORITY: u8 = 90;

/// A late wake-up of a stall probe: it was due at `due` and woke `late`
/// after.
#[derive(Debug, Clone, Copy)]
struct Stall {
    due: Instant,
    late: Duration,
}

impl Stall {
    /// Whether the stall overlaps the interval `from..=to`.
    fn overlaps(&self, from: Instant, to: Instant) -> bool {
        self.due <= to && self.due + self.late >= from
    }
}

/// Sleeps the calling thread until `due` (returns at once if it is past).
fn sleep_until(due: Instant) {
    let now = Instant::now();
    if due > now {
        std::thread::sleep(due - now);
    }
}

/// A stall probe: on CPU `cpu` (pinned where permitted), real-time at
/// `rt_priority` where permitted (0: normal priority, and the probe then also
/// sees the delays of the run's own threads), sleeps to the `n` ticks of
/// `period` from `start` (offset by half a period, between the clients'
/// ticks) and records
/// the wake-ups later than [`STALL_THRESHOLD_US`]. It measures the machine
/// (the hypervisor, the kernel, other tenants), not the server: it does
/// nothing but sleep.
fn stall_probe(
    cpu: usize,
    rt_priority: u8,
    start: Instant,
    period: Duration,
    n: u64,
) -> Vec<Stall> {
    if let Err(why) = priority::pin_current_thread(cpu) {
        tracing::debug!(cpu, %why, "stall probe not pinned");
    }
    let _ = priority::raise_current_thread(rt_priority);
    let threshold = Duration::from_secs_f64(STALL_THRESHOLD_US * 1e-6);
    let mut stalls = Vec::new();
    for k in 0..n {
        let due = start + period.mul_f64(k as f64 + 0.5);
        sleep_until(due);
        let late = Instant::now().saturating_duration_since(due);
        if late > threshold {
            stalls.push(Stall { due, late });
        }
    }
    stalls
}

/// Pose `k` of a ping-pong walk over the trajectory's waypoints.
fn ping_pong(points: &[Waypoint], k: u64) -> &Waypoint {
    let m = points.len() as u64;
    if m < 2 {
        return &points[0];
    }
    let j = k % (2 * (m - 1));
    let i = if j < m { j } else { 2 * (m - 1) - j };
    &points[i as usize]
}

/// Runs the benchmark.
pub async fn run(args: &LoopBenchArgs) -> anyhow::Result<LoopBenchReport> {
    if !(args.duration_s > 0.0 && args.rate_hz > 0.0) {
        bail!("--duration-s and --rate-hz must be positive");
    }
    let (mut scene, _) =
        Scene::load(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    if let Some(t) = args.traversal {
        scene.collision.traversal = t;
    }
    let traversal = scene.collision.traversal;
    let mut plans: Vec<(String, Trajectory)> = Vec::new();
    for spec in &scene.instruments {
        if let Some(b) = BUNDLED
            .iter()
            .find(|b| b.1 == scene.name && b.2 == spec.name)
        {
            plans.push((spec.name.clone(), Trajectory::load(b.0)?));
        }
    }
    if plans.is_empty() {
        bail!(
            "scene {:?} has no bundled trajectories to drive its instruments",
            scene.name
        );
    }
    let options = SimOptions {
        mode: Some(Mode::FreeRunning),
        max_watchers: args.watchers + 1,
        force_loop_rt_priority: args.rt_priority,
        ..SimOptions::default()
    };
    let scene_name = scene.name.clone();
    let loading = Instant::now();
    let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
    let load_s = loading.elapsed().as_secs_f64();
    // The server's transport on its own runtime, as `fissure-server` runs it;
    // the clients below have runtimes of their own, as separate processes do.
    let transport = Transport::new(args.transport_rt_priority)?;
    let server = transport
        .serve("127.0.0.1:0".parse()?, ServeOptions::default())
        .await?;
    server.set_simulation(sim.clone()).await;
    let url = format!("http://{}", server.addr);
    let result = drive(args, &url, &sim, &plans).await;
    server.shutdown().await?;
    let transport_realtime = transport.realtime();
    drop(transport);
    tokio::task::spawn_blocking({
        let sim = sim.clone();
        move || sim.shutdown()
    })
    .await?;
    let mut report = result?;
    report.scene = scene_name;
    report.load_s = load_s;
    report.traversal = traversal.name().into();
    report.transport_realtime = transport_realtime;
    report.surface_triangles = sim.model().surface.triangles.len();
    Ok(report)
}

async fn drive(
    args: &LoopBenchArgs,
    url: &str,
    sim: &Arc<Simulation>,
    plans: &[(String, Trajectory)],
) -> anyhow::Result<LoopBenchReport> {
    // Watchers: each on its own connection, full frames; frames are counted
    // while the clock runs.
    let counting = Arc::new(AtomicBool::new(false));
    let mut watchers = Vec::new();
    for _ in 0..args.watchers {
        let mut client = connect(url).await?;
        let mut stream = client
            .watch(pb::WatchRequest {
                include_positions: true,
            })
            .await?
            .into_inner();
        let counting = counting.clone();
        let count = Arc::new(AtomicU64::new(0));
        let counter = count.clone();
        let task = tokio::spawn(async move {
            let _client = client;
            while let Ok(Some(_)) = stream.message().await {
                if counting.load(Ordering::Relaxed) {
                    counter.fetch_add(1, Ordering::Relaxed);
                }
            }
        });
        watchers.push((task, count));
    }

    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let n = (args.duration_s * args.rate_hz).round() as u64;
    let rt_priority = args.rt_priority;
    // Whether every client thread got its real-time priority (the server's
    // force loops ask the same of the same process's permissions).
    let realtime = Arc::new(AtomicBool::new(rt_priority > 0));
    // Each client is a device bridge of its own: a connection thread with
    // its own single-threaded runtime (its I/O never waits for the server's
    // runtime) and a servo thread sending the poses on their ticks.
    let mut receivers = Vec::new();
    let mut txs = Vec::new();
    for (name, trajectory) in plans {
        let (tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(4096);
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel::<anyhow::Result<()>>(1);
        let (url, name) = (url.to_owned(), name.clone());
        let realtime_conn = realtime.clone();
        let conn = std::thread::Builder::new()
            .name("bench-client-io".into())
            .spawn(move || -> anyhow::Result<Vec<Answer>> {
                let rt_ok = priority::raise_current_thread(rt_priority).unwrap_or(false);
                realtime_conn.fetch_and(rt_ok, Ordering::Relaxed);
                let rt = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .context("starting a client runtime")?;
                rt.block_on(async move {
                    let claimed = async {
                        let mut client = connect(&url).await?;
                        let req = haptic_request(
                            tokio_stream::wrappers::ReceiverStream::new(rx),
                            &name,
                            None,
                        )?;
                        let inbound = client
                            .haptic(req)
                            .await
                            .with_context(|| format!("claiming instrument {name:?}"))?
                            .into_inner();
                        anyhow::Ok((client, inbound))
                    }
                    .await;
                    let (client, mut inbound) = match claimed {
                        Ok(c) => {
                            let _ = ready_tx.send(Ok(()));
                            c
                        }
                        Err(e) => {
                            let _ = ready_tx.send(Err(anyhow::anyhow!("{e:#}")));
                            return Err(e);
                        }
                    };
                    let _client = client;
                    let mut answers = Vec::with_capacity(n as usize);
                    while let Ok(Some(s)) = inbound.message().await {
                        answers.push(Answer {
                            sequence: s.sequence,
                            arrived: Instant::now(),
                            server_us: s.server_compute_us,
                            model_age_s: s.model_age_s,
                            contact_count: s.contact_count,
                            pending: s.safety_flags & fissure_engine::sim::flags::COLUMNS_PENDING
                                != 0,
                            rejected: s.rejection.is_some(),
                        });
                    }
                    Ok(answers)
                })
            })
            .context("starting a client thread")?;
        tokio::task::spawn_blocking(move || ready_rx.recv())
            .await?
            .map_err(|_| anyhow::anyhow!("a client thread ended before claiming"))??;
        receivers.push(conn);
        txs.push((tx, trajectory.clone()));
    }
    let start = Instant::now() + Duration::from_millis(50);
    let frame_at_start = {
        tokio::time::sleep_until(start.into()).await;
        counting.store(true, Ordering::Relaxed);
        sim.snapshot().frame
    };
    let mut senders = Vec::new();
    for (tx, trajectory) in txs {
        let realtime_clients = realtime.clone();
        senders.push(
            std::thread::Builder::new()
                .name("bench-haptic-client".into())
                .spawn(move || {
                    let realtime = priority::raise_current_thread(rt_priority).unwrap_or(false);
                    realtime_clients.fetch_and(realtime, Ordering::Relaxed);
                    let mut sent = Vec::with_capacity(n as usize);
                    for k in 0..n {
                        sleep_until(start + period.mul_f64(k as f64));
                        let p = ping_pong(&trajectory.points, k);
                        let mut msg = crate::client::replay::pose_message(p, k + 1);
                        msg.t_s = k as f64 * period.as_secs_f64();
                        sent.push(Instant::now());
                        if tx.blocking_send(msg).is_err() {
                            break;
                        }
                    }
                    sent
                })
                .context("starting a client thread")?,
        );
    }
    // One stall probe per CPU: the machine's own ability to hold the ticks.
    let mut probes = Vec::new();
    for cpu in priority::allowed_cpus().unwrap_or_default() {
        probes.push(
            std::thread::Builder::new()
                .name("bench-stall-probe".into())
                .spawn(move || {
                    let probe_priority = if rt_priority > 0 {
                        STALL_PROBE_RT_PRIORITY
                    } else {
                        0
                    };
                    stall_probe(cpu, probe_priority, start, period, n)
                })
                .context("starting a stall probe")?,
        );
    }
    let mut sent_all = Vec::new();
    for s in senders {
        sent_all.push(
            tokio::task::spawn_blocking(move || s.join())
                .await?
                .map_err(|_| anyhow::anyhow!("a client thread panicked"))?,
        );
    }
    let end = Instant::now();
    let frame_at_end = sim.snapshot().frame;
    let mut stalls = Vec::new();
    let probe_cpus = probes.len();
    for p in probes {
        stalls.extend(
            tokio::task::spawn_blocking(move || p.join())
                .await?
                .map_err(|_| anyhow::anyhow!("a stall probe panicked"))?,
        );
    }
    counting.store(false, Ordering::Relaxed);
    let mut answers_all = Vec::new();
    for r in receivers {
        let joined = tokio::time::timeout(
            Duration::from_secs(10),
            tokio::task::spawn_blocking(move || r.join()),
        )
        .await
        .context("the server did not end a haptic stream")??;
        answers_all.push(joined.map_err(|_| anyhow::anyhow!("a client thread panicked"))??);
    }
    let mut delivered = Vec::new();
    for (task, count) in watchers {
        task.abort();
        delivered.push(count.load(Ordering::Relaxed));
    }
    let delivered_total: u64 = delivered.iter().sum();

    let mut rtt = Vec::new();
    let mut server = Vec::new();
    let mut lag = Vec::new();
    let mut missed = 0u64;
    let mut missed_by_round_trip = 0u64;
    let mut missed_outside_stalls = 0u64;
    let mut answered = 0u64;
    let mut pending = 0u64;
    let mut sent_total = 0u64;
    let (mut age_max, mut contact_max) = (0.0f64, 0u32);
    for (sent, answers) in sent_all.iter().zip(&answers_all) {
        sent_total += sent.len() as u64;
        let mut arrival: Vec<Option<&Answer>> = vec![None; sent.len()];
        for a in answers {
            let k = a.sequence.wrapping_sub(1) as usize;
            if k < arrival.len() && !a.rejected {
                arrival[k] = Some(a);
            }
        }
        for (k, (&at, a)) in sent.iter().zip(&arrival).enumerate() {
            let due = start + period.mul_f64(k as f64);
            lag.push(at.saturating_duration_since(due).as_secs_f64() * 1e6);
            let next_due = start + period.mul_f64((k + 1) as f64);
            match a {
                Some(a) => {
                    answered += 1;
                    pending += a.pending as u64;
                    rtt.push(a.arrived.saturating_duration_since(at).as_secs_f64() * 1e6);
                    server.push(a.server_us);
                    age_max = age_max.max(a.model_age_s);
                    contact_max = contact_max.max(a.contact_count);
                    if a.arrived > next_due {
                        missed += 1;
                        if a.arrived.saturating_duration_since(at) > period {
                            missed_by_round_trip += 1;
                        }
                        if !stalls.iter().any(|s| s.overlaps(due, a.arrived)) {
                            missed_outside_stalls += 1;
                        }
                    }
                }
                None => {
                    missed += 1;
                    missed_by_round_trip += 1;
                    if !stalls.iter().any(|s| s.overlaps(due, end)) {
                        missed_outside_stalls += 1;
                    }
                }
            }
        }
    }
    for v in [&mut rtt, &mut server, &mut lag] {
        v.sort_by(f64::total_cmp);
    }
    let last = |v: &[f64]| v.last().copied().unwrap_or(f64::NAN);
    let stats = sim.stats();
    let duration = end.duration_since(start).as_secs_f64();
    let frames_published = frame_at_end.saturating_sub(frame_at_start);
    Ok(LoopBenchReport {
        duration_s: duration,
        rate_hz: args.rate_hz,
        clients: plans.len(),
        watchers: args.watchers,
        realtime: realtime.load(Ordering::Relaxed),
        samples_sent: sent_total,
        samples_answered: answered,
        samples_pending: pending,
        missed_samples: missed,
        missed_by_round_trip,
        missed_outside_stalls,
        machine_stalls: stalls.len() as u64,
        machine_stall_max_us: stalls
            .iter()
            .map(|s| s.late.as_secs_f64() * 1e6)
            .fold(0.0, f64::max),
        stall_probe_cpus: probe_cpus,
        rtt_p50_us: percentile(&rtt, 0.5),
        rtt_p99_us: percentile(&rtt, 0.99),
        rtt_max_us: last(&rtt),
        server_force_p50_us: percentile(&server, 0.5),
        server_force_p99_us: percentile(&server, 0.99),
        server_force_max_us: last(&server),
        force_collision_p50_us: stats.force_collision.p50_us,
        force_collision_p99_us: stats.force_collision.p99_us,
        force_collision_max_us: stats.force_collision.max_us,
        send_lag_p99_us: percentile(&lag, 0.99),
        deform_hz: frames_published as f64 / duration,
        deform_step_p50_ms: stats.deformation_step.p50_us / 1e3,
        deform_step_p99_ms: stats.deformation_step.p99_us / 1e3,
        frames_published,
        frames_delivered: delivered_total,
        frames_delivered_min: delivered.iter().copied().min().unwrap_or(0),
        model_age_max_ms: age_max * 1e3,
        contact_count_max: contact_max,
        failed_steps: stats.failed_steps,
        ..Default::default()
    })
}

/// The report as a table.
pub fn table(r: &LoopBenchReport) -> String {
    let mut s = format!(
        "bench loop — scene {} ({} surface triangles, loaded in {:.1} s, BVH traversal {}), free-running\n\
         {} clients at {:.0} Hz (real-time ticks), {} watchers (full frames), {:.2} s\n\
         force loops and client threads: {}, server transport: {}\n\n",
        r.scene,
        r.surface_triangles,
        r.load_s,
        r.traversal,
        r.clients,
        r.rate_hz,
        r.watchers,
        r.duration_s,
        if r.realtime {
            "SCHED_FIFO"
        } else {
            "normal priority"
        },
        if r.transport_realtime {
            "SCHED_FIFO"
        } else {
            "normal priority"
        }
    );
    let row = |name: &str, p50: f64, p99: f64, max: f64| {
        format!("{name:<28} {p50:>10.1} {p99:>10.1} {max:>10.1}\n")
    };
    s.push_str(&format!(
        "{:<28} {:>10} {:>10} {:>10}\n",
        "latency (us)", "p50", "p99", "max"
    ));
    s.push_str(&row(
        "server force computation",
        r.server_force_p50_us,
        r.server_force_p99_us,
        r.server_force_max_us,
    ));
    s.push_str(&row(
        "  of which collision query",
        r.force_collision_p50_us,
        r.force_collision_p99_us,
        r.force_collision_max_us,
    ));
    s.push_str(&row("round trip", r.rtt_p50_us, r.rtt_p99_us, r.rtt_max_us));
    s.push_str(&format!(
        "\nsamples sent {}, answered {} ({} with a penalty estimate: compliance pending), \
         missed {} (answer after the next tick or never; \
         {} of them by a round trip over one period, {} outside machine stalls)\n\
         machine: {} stalls (stall probes on {} CPUs woke over {:.0} us late), max {:.0} us\n\
         client send lag p99 {:.1} us\n\
         deformation: {:.1} Hz, step p50 {:.2} ms, p99 {:.2} ms, {} frames, {} failed\n\
         watchers: {} frames delivered in all, {} to the slowest\n\
         model age max {:.1} ms, contact count max {}\n",
        r.samples_sent,
        r.samples_answered,
        r.samples_pending,
        r.missed_samples,
        r.missed_by_round_trip,
        r.missed_outside_stalls,
        r.machine_stalls,
        r.stall_probe_cpus,
        STALL_THRESHOLD_US,
        r.machine_stall_max_us,
        r.send_lag_p99_us,
        r.deform_hz,
        r.deform_step_p50_ms,
        r.deform_step_p99_ms,
        r.frames_published,
        r.failed_steps,
        r.frames_delivered,
        r.frames_delivered_min,
        r.model_age_max_ms,
        r.contact_count_max
    ));
    s
}

/// A scene against a baseline scene (`--baseline-scene`): the median over
/// the rounds of each round's ratio, scene over baseline (`None` where a
/// baseline figure was 0 in some round).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LoopRatios {
    /// The scene measured.
    pub scene: String,
    /// The baseline it is divided by.
    pub baseline: String,
    /// Rounds (pairs of runs).
    pub rounds: usize,
    /// Deformation step, median.
    pub deform_step_p50: Option<f64>,
    /// Deformation step, 99th percentile.
    pub deform_step_p99: Option<f64>,
    /// Server force computation, median.
    pub server_force_p50: Option<f64>,
    /// Server force computation, 99th percentile.
    pub server_force_p99: Option<f64>,
    /// Model age, maximum.
    pub model_age_max: Option<f64>,
}

/// The median of each round's ratio `scene / baseline` of the figures
/// `pairs` holds as `(baseline, scene)` runs.
pub fn ratios(pairs: &[(LoopBenchReport, LoopBenchReport)]) -> LoopRatios {
    let median_ratio = |f: fn(&LoopBenchReport) -> f64| -> Option<f64> {
        let mut r: Vec<f64> = pairs
            .iter()
            .map(|(b, s)| (f(b) > 0.0).then(|| f(s) / f(b)))
            .collect::<Option<_>>()?;
        if r.is_empty() {
            return None;
        }
        r.sort_by(f64::total_cmp);
        let m = r.len() / 2;
        Some(if r.len() % 2 == 1 {
            r[m]
        } else {
            0.5 * (r[m - 1] + r[m])
        })
    };
    let (baseline, scene) = pairs
        .first()
        .map(|(b, s)| (b.scene.clone(), s.scene.clone()))
        .unwrap_or_default();
    LoopRatios {
        scene,
        baseline,
        rounds: pairs.len(),
        deform_step_p50: median_ratio(|r| r.deform_step_p50_ms),
        deform_step_p99: median_ratio(|r| r.deform_step_p99_ms),
        server_force_p50: median_ratio(|r| r.server_force_p50_us),
        server_force_p99: median_ratio(|r| r.server_force_p99_us),
        model_age_max: median_ratio(|r| r.model_age_max_ms),
    }
}

/// The ratios as a table.
pub fn ratios_table(r: &LoopRatios) -> String {
    let f = |v: Option<f64>| v.map_or_else(|| "-".to_owned(), |v| format!("{v:.2}"));
    format!(
        "{} over {} (median of {} paired rounds)\n\
         deformation step p50 {}, p99 {}; server force p50 {}, p99 {}; model age max {}\n",
        r.scene,
        r.baseline,
        r.rounds,
        f(r.deform_step_p50),
        f(r.deform_step_p99),
        f(r.server_force_p50),
        f(r.server_force_p99),
        f(r.model_age_max)
    )
}

/// What `--baseline-scene` prints as JSON: every run, then the ratios.
#[derive(Debug, serde::Serialize)]
struct PairedReport {
    runs: Vec<LoopBenchReport>,
    ratios: LoopRatios,
}

/// Runs the benchmark and prints JSON or a table.
pub async fn main(args: &LoopBenchArgs) -> anyhow::Result<()> {
    let Some(baseline) = &args.baseline_scene else {
        let report = run(args).await?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{}", table(&report));
        }
        return Ok(());
    };
    let base_args = LoopBenchArgs {
        scene: baseline.clone(),
        ..args.clone()
    };
    let mut pairs = Vec::new();
    for round in 1..=args.rounds {
        let b = run(&base_args)
            .await
            .with_context(|| format!("round {round}, baseline scene {baseline:?}"))?;
        let s = run(args)
            .await
            .with_context(|| format!("round {round}, scene {:?}", args.scene))?;
        if !args.json {
            println!("round {round} of {}", args.rounds);
            print!("{}\n{}\n", table(&b), table(&s));
        }
        pairs.push((b, s));
    }
    let r = ratios(&pairs);
    if args.json {
        let runs = pairs.into_iter().flat_map(|(b, s)| [b, s]).collect();
        let out = PairedReport { runs, ratios: r };
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print!("{}", ratios_table(&r));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_are_the_median_of_each_rounds_pair() {
        let run = |scene: &str, step_p99: f64, force_p99: f64| LoopBenchReport {
            scene: scene.to_owned(),
            deform_step_p50_ms: 10.0,
            deform_step_p99_ms: step_p99,
            server_force_p99_us: force_p99,
            ..Default::default()
        };
        // The machine slows down over the rounds: the pairs keep the ratio.
        let pairs = vec![
            (run("base", 20.0, 100.0), run("ties", 40.0, 150.0)),
            (run("base", 40.0, 200.0), run("ties", 120.0, 300.0)),
            (run("base", 80.0, 400.0), run("ties", 200.0, 1200.0)),
        ];
        let r = ratios(&pairs);
        assert_eq!(
            (r.scene.as_str(), r.baseline.as_str(), r.rounds),
            ("ties", "base", 3)
        );
        assert_eq!(r.deform_step_p99, Some(2.5)); // of 2, 3, 2.5
        assert_eq!(r.server_force_p99, Some(1.5)); // of 1.5, 1.5, 3
        assert_eq!(r.deform_step_p50, Some(1.0));
        // A baseline figure of 0 gives no ratio; an even count, the middle two's mean.
        assert_eq!(r.server_force_p50, None);
        assert_eq!(ratios(&pairs[..2]).deform_step_p99, Some(2.5));
        assert_eq!(ratios(&[]).deform_step_p99, None);
    }

    #[test]
    fn ping_pong_walks_forwards_then_back() {
        let w = |t: f64| Waypoint {
            t_s: t,
            x_m: t,
            y_m: 0.0,
            z_m: 0.0,
            qw: 1.0,
            qx: 0.0,
            qy: 0.0,
            qz: 0.0,
        };
        let pts: Vec<Waypoint> = (0..4).map(|i| w(i as f64)).collect();
        let xs: Vec<f64> = (0..9).map(|k| ping_pong(&pts, k).x_m).collect();
        assert_eq!(xs, [0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0, 1.0, 2.0]);
        assert_eq!(ping_pong(&pts[..1], 5).x_m, 0.0);
    }

    #[test]
    fn a_stall_explains_the_samples_whose_interval_it_touches() {
        let t0 = Instant::now();
        let ms = |x: f64| t0 + Duration::from_secs_f64(x * 1e-3);
        // Due at 10 ms, woke 1.5 ms late: covers 10..11.5 ms.
        let s = Stall {
            due: ms(10.0),
            late: Duration::from_micros(1500),
        };
        // A sample sent at 9 ms and answered at 10.2 ms: inside.
        assert!(s.overlaps(ms(9.0), ms(10.2)));
        // One spanning the whole stall, one starting inside it.
        assert!(s.overlaps(ms(9.5), ms(12.0)));
        assert!(s.overlaps(ms(11.0), ms(12.4)));
        // Touching ends count.
        assert!(s.overlaps(ms(11.5), ms(12.0)));
        assert!(s.overlaps(ms(8.0), ms(10.0)));
        // Wholly before or after: not explained.
        assert!(!s.overlaps(ms(7.0), ms(9.9)));
        assert!(!s.overlaps(ms(11.6), ms(12.8)));
    }

    #[test]
    fn a_stall_probe_reports_only_late_wake_ups() {
        let period = Duration::from_millis(1);
        let start = Instant::now();
        let stalls = stall_probe(0, 0, start, period, 50);
        assert!(stalls.len() <= 50);
        for s in &stalls {
            assert!(s.late.as_secs_f64() * 1e6 > STALL_THRESHOLD_US);
            assert!(s.due >= start && s.due <= start + period.mul_f64(50.0));
        }
        // The probe slept to its last tick.
        assert!(start.elapsed() >= period.mul_f64(49.5));
    }
}
