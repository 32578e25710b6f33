//! The two loops through the gRPC service: in free-running mode the force loop
//! never waits for the deformation loop and watchers are latest-wins; in
//! stepped mode two runs of the same two-instrument session are bit-identical.

use fissure_cli::client::replay::{ForceRow, Pacing, connect, replay};
use fissure_cli::client::trajectory::Trajectory;
use fissure_engine::scene::{ModelSpec, Scene, Strategy};
use fissure_engine::sim::{Mode, SimOptions, flags};
use fissure_proto::recording;
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_server::recording::ToFile;
use fissure_tests::{Haptic, TestServer, pose};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Lays the plate flat, face A down, tip towards +y (see cube.toml).
const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Handle height at which face A touches the cube's top (z = 40 mm), m.
const TOUCH_Z: f64 = 0.04 + 0.00075;

fn free_running() -> SimOptions {
    SimOptions {
        mode: Some(Mode::FreeRunning),
        ..SimOptions::default()
    }
}

/// The left spatula's handle at pose time `t` (s): 0.5 mm into the cube's
/// top at first, pushing to 2 mm and back once a second (the contact changes
/// at every deformation step).
fn pressing(t: f64) -> [f64; 3] {
    let s = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * t).cos();
    [0.011, 0.005, TOUCH_Z - 0.0005 - 0.0015 * s]
}

/// Sends `n` poses of `path` paced at 1 kHz on the wall clock (pose `i` not
/// before `i` ms after the start) and returns the answers with their round
/// trips, us.
async fn paced(
    haptic: &mut Haptic,
    n: u64,
    path: impl Fn(f64) -> [f64; 3],
) -> anyhow::Result<Vec<(pb::ForceSample, f64)>> {
    let start = tokio::time::Instant::now();
    let mut out = Vec::with_capacity(n as usize);
    for i in 0..n {
        tokio::time::sleep_until(start + Duration::from_millis(i)).await;
        let t = i as f64 * 1e-3;
        let sent = Instant::now();
        let s = haptic.send(pose(t, i + 1, path(t), FLAT_DOWN)).await?;
        out.push((s, sent.elapsed().as_secs_f64() * 1e6));
    }
    Ok(out)
}

/// A deformation step far slower than the haptic period (the `neo-hookean`
/// strategy on a 12-cell cube: up to seconds a step with a new contact): force
/// samples keep coming at the haptic rate with small server compute times while
/// the model they use ages, past the staleness limit (10 deformation intervals,
/// then flagged MODEL_STALE); the force loop never waits for a step.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_loop_never_waits_for_a_slow_deformation_step() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let (mut scene, _) = Scene::load("cube")?;
    scene.solver.strategy = Strategy::NeoHookean;
    // A tight tolerance keeps the steps slow (several Newton iterations).
    scene.solver.tolerance = 1e-10;
    scene.model = ModelSpec::Cube {
        size_m: 0.04,
        cells: 12,
    };
    // A short interval, so that a step (over 100 ms on a fast idle machine)
    // outlasts 10 intervals and the model goes stale while it runs (with the
    // scene's 20 ms that needed steps over 200 ms, which only a loaded
    // machine gave).
    scene.loops.deformation_interval_s = 0.005;
    let dt = scene.loops.deformation_interval_s;
    let server = TestServer::start_scene(scene, free_running(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let n = 1500;
    let wall = Instant::now();
    let samples = paced(&mut haptic, n, pressing).await?;
    let wall_s = wall.elapsed().as_secs_f64();
    haptic.close().await;
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    server.stop().await?;

    let step = stats.deformation_step.expect("step latency");
    // The premise: steps much slower (over 50x) than the 1 ms haptic period (the longest
    // decides; steps whose contact barely changed converge faster).
    // A step still running at the end counts too: the samples' model age
    // (pose time since the frame they use) bounds its length from below.
    let oldest_model_s = samples
        .iter()
        .map(|(s, _)| s.model_age_s)
        .fold(0.0f64, f64::max);
    let slow_us = step.max_us.max((oldest_model_s - dt) * 1e6);
    assert!(
        slow_us > 50_000.0,
        "deformation steps are not slow: {step:?}, oldest model {oldest_model_s} s"
    );
    // Every pose answered, in order, none rejected.
    assert_eq!(samples.len() as u64, n);
    for (i, (s, _)) in samples.iter().enumerate() {
        assert_eq!(s.sequence, i as u64 + 1);
        assert!(s.rejection.is_none(), "{:?}", s.rejection);
    }
    // The samples kept (about) the haptic pace: had the force loop waited for
    // steps, samples would come about once per step time. The bound leaves
    // room for a loaded machine (the solver's threads share the cores).
    assert!(
        wall_s < 2.0 * n as f64 * 1e-3,
        "{n} paced samples took {wall_s:.3} s with steps up to {:.3} s",
        slow_us * 1e-6
    );
    let mut server_us: Vec<f64> = samples.iter().map(|s| s.0.server_compute_us).collect();
    let mut rtt_us: Vec<f64> = samples.iter().map(|s| s.1).collect();
    server_us.sort_by(f64::total_cmp);
    rtt_us.sort_by(f64::total_cmp);
    let server_max = *server_us.last().expect("samples");
    let rtt_p99 = rtt_us[rtt_us.len() * 99 / 100];
    eprintln!(
        "{n} samples in {wall_s:.3} s; server compute p50 {:.0} us, max {server_max:.0} us; \
         round trip p50 {:.0} us, p99 {rtt_p99:.0} us; steps: {step:?}",
        server_us[server_us.len() / 2],
        rtt_us[rtt_us.len() / 2],
    );
    assert!(
        server_max < 0.05 * slow_us,
        "a force sample took {server_max:.0} us of server time, steps up to {slow_us:.0} us"
    );
    assert!(
        rtt_p99 < 0.05 * slow_us,
        "round trip p99 {rtt_p99:.0} us, steps up to {slow_us:.0} us"
    );
    // The model ages while a step runs: within a run of samples on the same
    // frame, model_age_s grows with the pose clock, past 10 intervals (stale).
    let mut longest = 0.0f64;
    for w in samples.windows(2) {
        let (a, b) = (&w[0].0, &w[1].0);
        if a.model_frame == b.model_frame {
            assert!(
                b.model_age_s >= a.model_age_s,
                "model age went back on frame {}: {} -> {}",
                a.model_frame,
                a.model_age_s,
                b.model_age_s
            );
        } else {
            assert!(b.model_frame > a.model_frame, "model frame went back");
        }
        longest = longest.max(b.model_age_s);
    }
    assert!(
        longest > 10.0 * dt,
        "largest model age {longest} s, steps up to {} s",
        slow_us * 1e-6
    );
    for (s, _) in &samples {
        let stale = s.safety_flags & flags::MODEL_STALE != 0;
        assert_eq!(
            stale,
            s.model_age_s > 10.0 * dt,
            "age {} s, flags {:#x}",
            s.model_age_s,
            s.safety_flags
        );
    }
    // Many samples per frame: about one frame per step time.
    let frames: std::collections::BTreeSet<u64> = samples.iter().map(|s| s.0.model_frame).collect();
    assert!(
        frames.len() * 20 < samples.len(),
        "{} frames for {} samples",
        frames.len(),
        samples.len()
    );
    Ok(())
}

/// Watchers are latest-wins: a watcher that takes 150 ms per frame sees the
/// frame numbers skip (never a queue of old frames), while a fast watcher on
/// the same server keeps up with the deformation loop and ends on the latest
/// frame.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_watcher_skips_frames_fast_watcher_keeps_up() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let server = TestServer::start("cube", free_running(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    // Each watcher reads until told to stop (then drops its stream).
    let stop = tokio::sync::watch::Sender::new(false);
    let watch = |mut c: fissure_proto::v1::fissure_client::FissureClient<_>, delay_ms: u64| {
        let mut stopped = stop.subscribe();
        tokio::spawn(async move {
            let mut stream = c
                .watch(pb::WatchRequest {
                    include_positions: true,
                })
                .await?
                .into_inner();
            let mut seen = Vec::new();
            loop {
                let f = tokio::select! {
                    f = stream.message() => f?,
                    _ = stopped.wait_for(|s| *s) => break,
                };
                let Some(f) = f else { break };
                seen.push(f.frame);
                if delay_ms > 0 {
                    tokio::time::sleep(Duration::from_millis(delay_ms)).await;
                }
            }
            anyhow::Ok(seen)
        })
    };
    // The slow watcher's HTTP/2 stream window holds about one frame of this
    // surface: latest-wins is the server's (it sends the latest frame when the
    // transport has room); frames a client lets pile up in a large receive
    // window (hyper's default is 2 MiB) are delivered in order from there.
    let small_window = tonic::transport::Channel::from_shared(server.url.clone())?
        .initial_stream_window_size(Some(8 * 1024))
        .connect()
        .await?;
    let slow = watch(
        fissure_proto::v1::fissure_client::FissureClient::new(small_window),
        150,
    );
    let fast = watch(server.client().await?, 0);
    let first_frame = server.sim.snapshot().frame;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    // Moving contact for 1.5 s: the surface changes at every step.
    let samples = paced(&mut haptic, 1500, |t| {
        let [x, y, z] = pressing(t);
        [x + 0.004 * (t * 4.0).sin(), y, z]
    })
    .await?;
    assert!(samples.iter().all(|s| s.0.rejection.is_none()));
    haptic.close().await;
    // Let the last step reach the watchers.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let last_frame = server.sim.snapshot().frame;
    stop.send_replace(true);
    let slow = slow.await??;
    let fast = fast.await??;
    server.stop().await?;

    let published = last_frame - first_frame;
    assert!(published >= 20, "only {published} frames in 1.5 s");
    for (name, seen) in [("slow", &slow), ("fast", &fast)] {
        assert!(
            seen.windows(2).all(|w| w[1] > w[0]),
            "{name} watcher saw frames out of order: {seen:?}"
        );
    }
    assert!(
        slow.windows(2).any(|w| w[1] > w[0] + 1),
        "the slow watcher never skipped a frame: {slow:?}"
    );
    // A queue would hand the slow watcher every published frame; latest-wins
    // gives it a fraction (bounded by its reading time, not by the machine's
    // load, which stretches the whole run).
    assert!(
        2 * slow.len() as u64 <= published,
        "the slow watcher got {} of {published} frames: a queue? {slow:?}",
        slow.len()
    );
    assert!(
        fast.len() >= 3 * slow.len(),
        "fast {} vs slow {} frames",
        fast.len(),
        slow.len()
    );
    let during = fast.iter().filter(|&&f| f > first_frame).count() as u64;
    assert!(
        2 * during >= published,
        "the fast watcher got {during} of {published} frames"
    );
    assert_eq!(
        fast.last().copied(),
        Some(last_frame),
        "the fast watcher did not end on the latest frame"
    );
    Ok(())
}

/// A recorded entry with its wall-clock fields zeroed (server compute time of
/// force samples, stage timings of frames), as comparable data.
#[derive(Debug, Default, PartialEq)]
struct Session {
    forces: BTreeMap<String, Vec<pb::ForceSample>>,
    poses: BTreeMap<String, Vec<pb::PoseSample>>,
    frames: Vec<pb::DeformationFrame>,
}

fn session(path: &std::path::Path) -> anyhow::Result<Session> {
    let (entries, truncated) = recording::read(path)?;
    assert!(!truncated, "recording {} truncated", path.display());
    let mut s = Session::default();
    for e in entries {
        match e.entry {
            Some(pb::recording_entry::Entry::Force(f)) => {
                let mut sample = f.sample.expect("sample");
                sample.server_compute_us = 0.0;
                s.forces.entry(f.instrument).or_default().push(sample);
            }
            Some(pb::recording_entry::Entry::Pose(p)) => {
                s.poses
                    .entry(p.instrument)
                    .or_default()
                    .push(p.pose.expect("pose"));
            }
            Some(pb::recording_entry::Entry::Frame(mut f)) => {
                f.timings = None;
                s.frames.push(f);
            }
            _ => {}
        }
    }
    Ok(s)
}

/// Runs both bundled cube trajectories at once against a stepped server that
/// records to `path`; returns each instrument's force rows.
async fn stepped_session(
    path: &std::path::Path,
    trajectories: &[(&str, Trajectory)],
) -> anyhow::Result<Vec<(String, Vec<ForceRow>)>> {
    let options = SimOptions {
        mode: Some(Mode::Stepped {
            clients: trajectories.len(),
        }),
        recording: Some(ToFile::open_at(path)),
        ..SimOptions::default()
    };
    let server = TestServer::start("cube", options, ServeOptions::default()).await?;
    let mut tasks = Vec::new();
    for (name, trajectory) in trajectories {
        let (url, name, trajectory) = (server.url.clone(), name.to_string(), trajectory.clone());
        tasks.push(tokio::spawn(async move {
            let mut client = connect(&url).await?;
            let rows = replay(&mut client, &name, None, &trajectory, Pacing::Fast, |_| {}).await?;
            anyhow::Ok((name, rows))
        }));
    }
    let mut out = Vec::new();
    for t in tasks {
        out.push(t.await??);
    }
    let sim = server.sim.clone();
    server.stop().await?;
    tokio::task::spawn_blocking(move || sim.recorder().map_or(Ok(()), |r| r.finish())).await??;
    Ok(out)
}

/// Stepped mode: two runs of the same two-instrument session (the bundled
/// `cube-press-left/right`, streamed as fast as the server answers, so the
/// interleaving of the two clients differs between runs) give bit-identical
/// force samples (every field but the server's compute time) and frame
/// summaries (every field but the stage timings).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stepped_runs_are_bit_identical() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let trajectories = [
        ("left", Trajectory::load("cube-press-left")?),
        ("right", Trajectory::load("cube-press-right")?),
    ];
    let dir = tempfile::tempdir()?;
    let (a_path, b_path) = (dir.path().join("a.fsrec"), dir.path().join("b.fsrec"));
    let a_rows = stepped_session(&a_path, &trajectories).await?;
    let b_rows = stepped_session(&b_path, &trajectories).await?;
    let (a, b) = (session(&a_path)?, session(&b_path)?);

    // The runs did something worth comparing.
    let peak = a_rows
        .iter()
        .flat_map(|(_, rows)| rows)
        .map(|r| r.force_n[2])
        .fold(0.0, f64::max);
    assert!(peak > 0.01, "peak push force {peak} N");
    assert!(a.frames.len() >= 50, "{} frames", a.frames.len());
    for (name, t) in &trajectories {
        assert_eq!(a.forces[*name].len(), t.points.len(), "{name}");
    }

    // Client-side rows: every force component, to the bit.
    for ((na, ra), (nb, rb)) in a_rows.iter().zip(&b_rows) {
        assert_eq!(na, nb);
        assert_eq!(ra.len(), rb.len());
        for (x, y) in ra.iter().zip(rb) {
            let bits = |r: &ForceRow| {
                (
                    r.sequence,
                    r.t_s.to_bits(),
                    r.force_n.map(f64::to_bits),
                    r.torque_nm.map(f64::to_bits),
                    r.contact_count,
                    r.model_frame,
                    r.safety_flags,
                )
            };
            assert_eq!(bits(x), bits(y), "{na}: sample {}", x.sequence);
        }
    }
    // Recorded sessions: forces per instrument and every frame summary. Prost
    // messages compare f64 with ==, and -0.0 == 0.0, NaN != NaN: compare the
    // encodings, which are bitwise.
    use prost::Message;
    assert_eq!(a.poses, b.poses);
    for name in a.forces.keys() {
        let (fa, fb) = (&a.forces[name], &b.forces[name]);
        assert_eq!(fa.len(), fb.len(), "{name}");
        for (x, y) in fa.iter().zip(fb) {
            assert_eq!(
                x.encode_to_vec(),
                y.encode_to_vec(),
                "{name}: sample {}",
                x.sequence
            );
        }
    }
    assert_eq!(a.frames.len(), b.frames.len());
    for (x, y) in a.frames.iter().zip(&b.frames) {
        assert_eq!(x.encode_to_vec(), y.encode_to_vec(), "frame {}", x.frame);
    }
    Ok(())
}
