//! Faults: a client killed mid-stream, deformation steps that fail, shutdown
//! with open streams, SIGTERM of the server binary while it records a session. (Watchers that never read:
//! `isolated/reliability_watchers.rs`, alone in its process for its memory figures.)

use crate::reliability_common::*;
use fissure_engine::sim::{SimOptions, flags};
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A client whose connection dies while it holds the tissue 3 mm deep: the
/// instrument is released (stats, and a new claim succeeds), it goes home and
/// the tissue relaxes back to rest in the frames.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_client_releases_its_instrument_and_the_tissue_relaxes() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut observer = server.client().await?;
    let mut watch = observer
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    let url = server.url.clone();
    // The client runs on its own connection in a task that is aborted
    // mid-stream: its connection is dropped without closing the stream, as
    // when the client process is killed.
    let (pushed_tx, pushed_rx) = tokio::sync::oneshot::channel();
    let client_task = tokio::spawn(async move {
        let mut client = own_connection(&url).await?;
        let mut haptic = Haptic::open(&mut client, "left", None).await?;
        let mut pushed = Some(pushed_tx);
        for i in 0u64.. {
            let t = i as f64 * 1e-3;
            let z = TOUCH_Z + 0.001 - (t * 0.04).min(0.004);
            let s = haptic.send(flat_pose(t, i + 1, LEFT_X, z)).await?;
            if s.contact_count > 0 && t > 0.15 {
                if let Some(tx) = pushed.take() {
                    let _ = tx.send(());
                }
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        anyhow::Ok(())
    });
    tokio::time::timeout(Duration::from_secs(20), pushed_rx).await??;
    // The tissue is deformed.
    let deformed = loop {
        let f = next_frame(&mut watch).await?;
        if f.max_displacement_m > 1e-3 {
            break f;
        }
    };
    assert!(deformed.instruments.iter().any(|i| i.contact_vertices > 0));
    client_task.abort();
    let _ = client_task.await;
    // Released within 2 s.
    let sim = server.sim.clone();
    assert!(
        eventually(Duration::from_secs(2), || sim.stats().claimed.is_empty()).await,
        "still claimed: {:?}",
        sim.stats().claimed
    );
    // The tissue relaxes to rest.
    let start = Instant::now();
    loop {
        let f = next_frame(&mut watch).await?;
        if f.max_displacement_m < 1e-9 {
            assert!(
                f.instruments.iter().all(|i| i.contact_vertices == 0),
                "{:?}",
                f.instruments
            );
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "the tissue did not relax: {} m",
            f.max_displacement_m
        );
    }
    // The instrument can be claimed again and starts from rest.
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let s = haptic
        .send(flat_pose(0.0, 1, LEFT_X, TOUCH_Z + 0.001))
        .await?;
    assert!(s.rejection.is_none() && s.contact_count == 0, "{s:?}");
    haptic.close().await;
    server.stop().await
}

/// Neo-Hookean with one Newton iteration allowed cannot converge under a
/// push: frames carry `solver_error` with the tissue at the last good state
/// (rest), force samples carry SOLVER_FAILED and come from the last good local
/// model, stats count the failed steps; the stream keeps being served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failed_deformation_steps_serve_the_last_good_state() -> anyhow::Result<()> {
    let scene = cube_scene(&[
        ("cells = 8", "cells = 4"),
        (
            "strategy = \"compliance\"",
            "strategy = \"neo-hookean\"\nmax_iterations = 1",
        ),
    ]);
    let server =
        TestServer::start_scene(scene, SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let rest = next_frame(&mut watch).await?;
    assert!(rest.solver_error.is_empty());
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let mut flagged = 0;
    let mut failed_frame = None;
    for i in 0..400u64 {
        let t = i as f64 * 1e-3;
        let z = TOUCH_Z + 0.001 - (t * 0.04).min(0.003);
        let s = haptic.send(flat_pose(t, i + 1, LEFT_X, z)).await?;
        assert!(s.rejection.is_none());
        let f = s.force_n.expect("force");
        assert!(f.x.is_finite() && f.y.is_finite() && f.z.is_finite());
        if s.safety_flags & flags::SOLVER_FAILED != 0 {
            flagged += 1;
            // The last good state is the rest state: the force loop answers
            // on its tangent (the rest stiffness), so the tissue pushes the
            // plate back up, never pulls it, and only along the press.
            assert!(f.z >= 0.0 && f.x.abs() < 1e-9 && f.y.abs() < 1e-9, "{s:?}");
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    while let Ok(Ok(Some(f))) =
        tokio::time::timeout(Duration::from_millis(200), watch.message()).await
    {
        if !f.solver_error.is_empty() {
            failed_frame = Some(f);
        }
    }
    let failed = failed_frame.expect("no frame reported the failed step");
    assert!(
        failed.solver_error.contains("did not converge") || failed.solver_error.contains("invert"),
        "{}",
        failed.solver_error
    );
    assert_eq!(
        failed.positions_m, rest.positions_m,
        "a failed step must keep the last good positions"
    );
    assert!(flagged > 0, "no force sample carried SOLVER_FAILED");
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert!(stats.failed_steps > 0);
    haptic.close().await;
    server.stop().await
}

/// Shutting the server down with a watcher and a haptic client still
/// streaming: both streams end with UNAVAILABLE and the shutdown completes at
/// once (not after the clients leave, nor after the grace period).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_open_streams() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    next_frame(&mut watch).await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let s = haptic.send(flat_pose(0.0, 1, LEFT_X, TOUCH_Z)).await?;
    assert!(s.rejection.is_none());
    let start = Instant::now();
    tokio::time::timeout(Duration::from_secs(3), server.stop()).await??;
    let took = start.elapsed();
    let end = loop {
        match tokio::time::timeout(Duration::from_secs(2), watch.message()).await? {
            Ok(Some(_)) => continue,
            Ok(None) => anyhow::bail!("the watch stream ended without a status"),
            Err(status) => break status,
        }
    };
    assert_eq!(end.code(), tonic::Code::Unavailable, "{end}");
    let err = haptic.send(flat_pose(0.001, 2, LEFT_X, TOUCH_Z)).await;
    assert!(err.is_err(), "the haptic stream is still served");
    eprintln!("shutdown with open streams took {took:?}");
    Ok(())
}

/// The address a starting server logs (`addr=...`), and its stderr lines.
fn spawn_server(args: &[&str]) -> (std::process::Child, std::sync::mpsc::Receiver<String>) {
    let mut child = Command::new(server_binary())
        .args(args)
        .env("NO_COLOR", "1")
        .env("FISSURE_LOG", "info")
        .env_remove("FISSURE_TOKEN")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning fissure-server");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    (child, rx)
}

fn wait_line(rx: &std::sync::mpsc::Receiver<String>, needle: &str, limit: Duration) -> String {
    let end = Instant::now() + limit;
    let mut seen = Vec::new();
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        match rx.recv_timeout(left) {
            Ok(line) if line.contains(needle) => return line,
            Ok(line) => seen.push(line),
            Err(_) => break,
        }
    }
    panic!(
        "no line with {needle:?} within {limit:?}; got:\n{}",
        seen.join("\n")
    );
}

/// SIGTERM while a client streams poses and a watcher is connected: the
/// server exits 0 within 10 s and the recording is complete: a header, every
/// pose the client was answered for recorded with its force, frames, nothing
/// truncated.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_mid_session_completes_the_recording() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let recording = dir.path().join("session.fissure");
    let rec = recording.to_str().expect("utf-8 path");
    let (mut child, lines) = spawn_server(&[
        "--scene",
        "cube",
        "--listen",
        "127.0.0.1:0",
        "--record",
        rec,
    ]);
    let line = wait_line(&lines, "listening", Duration::from_secs(60));
    let addr = line
        .split_whitespace()
        .find_map(|w| w.strip_prefix("addr="))
        .expect("addr= in the log line")
        .to_owned();
    wait_line(&lines, "serving", Duration::from_secs(60));
    let url = format!("http://{addr}");
    let mut client = own_connection(&url).await?;
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let mut answered = 0u64;
    for i in 0..300u64 {
        let t = i as f64 * 1e-3;
        let z = TOUCH_Z + 0.001 - (t * 0.02).min(0.003);
        let s = haptic.send(flat_pose(t, i + 1, LEFT_X, z)).await?;
        assert!(s.rejection.is_none());
        answered += 1;
    }
    next_frame(&mut watch).await?;
    // SIGTERM with both streams open.
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()?;
    assert!(status.success());
    let start = Instant::now();
    let exit = loop {
        if let Some(s) = child.try_wait()? {
            break s;
        }
        if start.elapsed() > Duration::from_secs(10) {
            child.kill()?;
            panic!("fissure-server did not exit within 10 s of SIGTERM");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(exit.success(), "fissure-server exited with {exit}");
    let (entries, truncated) = fissure_proto::recording::read(&recording)?;
    assert!(!truncated, "the recording ends with a truncated entry");
    use pb::recording_entry::Entry;
    let poses: Vec<u64> = entries
        .iter()
        .filter_map(|e| match &e.entry {
            Some(Entry::Pose(p)) => p.pose.as_ref().map(|p| p.sequence),
            _ => None,
        })
        .collect();
    let forces: Vec<u64> = entries
        .iter()
        .filter_map(|e| match &e.entry {
            Some(Entry::Force(f)) => f.sample.as_ref().map(|s| s.sequence),
            _ => None,
        })
        .collect();
    let frames = entries
        .iter()
        .filter(|e| matches!(e.entry, Some(Entry::Frame(_))))
        .count();
    assert!(matches!(entries[0].entry, Some(Entry::Header(_))));
    assert_eq!(poses, (1..=answered).collect::<Vec<_>>());
    assert_eq!(forces, poses, "every recorded pose has its force");
    assert!(frames > 0, "no frame recorded");
    eprintln!(
        "SIGTERM: exit in {:?}; recording: {} poses, {} forces, {frames} frames",
        start.elapsed(),
        poses.len(),
        forces.len()
    );
    drop(haptic);
    Ok(())
}
