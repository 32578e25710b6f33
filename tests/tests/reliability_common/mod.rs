//! Helpers of the reliability tests: the cube scene's geometry, scene variants,
//! process memory, pipelined haptic streams (poses sent on a clock, answers
//! read as they come) and latency percentiles.

#![allow(dead_code)]

use fissure_engine::scene::Scene;
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_client::FissureClient;
use std::path::PathBuf;
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tonic::transport::Channel;

/// Lays the plate flat, face A down (-z), tip towards +y (see cube.toml).
pub const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Handle height at which face A touches the cube's top (z = 40 mm), m.
pub const TOUCH_Z: f64 = 0.04 + 0.00075;
/// Handle x of the `left` and `right` instruments of the cube scene, m.
pub const LEFT_X: f64 = 0.011;
pub const RIGHT_X: f64 = 0.029;
/// Handle y of both instruments, m.
pub const HANDLE_Y: f64 = 0.005;

/// The cube scene's text with `(from, to)` replacements applied (each `from`
/// must occur), parsed.
pub fn cube_scene(replacements: &[(&str, &str)]) -> Scene {
    let mut text = include_str!("../../../server/scenes/cube.toml").to_owned();
    for (from, to) in replacements {
        assert!(text.contains(from), "cube.toml has no {from:?}");
        text = text.replacen(from, to, 1);
    }
    Scene::parse(&text, "cube (test variant)").expect("cube variant parses")
}

/// Resident set size of this process, bytes (`VmRSS` of /proc/self/status).
pub fn rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    let line = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .expect("VmRSS line");
    let kib: u64 = line
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .expect("VmRSS value");
    kib * 1024
}

/// A client on its own HTTP/2 connection (streams on one connection share
/// its flow-control window; a stalled stream must not stall the others).
pub async fn own_connection(url: &str) -> anyhow::Result<FissureClient<Channel>> {
    fissure_cli::client::replay::connect(url).await
}

/// A client on its own connection whose HTTP/2 receive windows are the
/// protocol's minimum default (64 KiB): what it does not read stays in the
/// server (the default client windows, 2 MiB a stream and 5 MiB a connection
/// in hyper, would let the client itself buffer that much).
pub async fn small_window_connection(url: &str) -> anyhow::Result<FissureClient<Channel>> {
    let channel = Channel::from_shared(url.to_owned())?
        .initial_stream_window_size(Some(65_535))
        .initial_connection_window_size(Some(65_535))
        .connect()
        .await?;
    Ok(FissureClient::new(channel))
}

/// The `q`-quantile (0..=1) of `values` (sorted in place), nearest rank.
pub fn quantile(values: &mut [f64], q: f64) -> f64 {
    assert!(!values.is_empty(), "no values");
    values.sort_by(f64::total_cmp);
    let rank = ((q * values.len() as f64).ceil() as usize).clamp(1, values.len());
    values[rank - 1]
}

/// What one pipelined haptic stream saw.
#[derive(Debug, Default)]
pub struct StreamReport {
    /// Poses sent.
    pub sent: u64,
    /// Answers received (not kept: the load tests measure the process's
    /// memory, clients included).
    pub answered: u64,
    /// Answers with a contact.
    pub touching: u64,
    /// Round trip of each answer (send to receive), microseconds.
    pub round_trip_us: Vec<f64>,
    /// Answers out of order or with a non-finite force.
    pub bad_answers: Vec<String>,
    /// Rejected poses: sequence, status code, message.
    pub rejected: Vec<(u64, i32, String)>,
}

impl StreamReport {
    /// Poses that got no answer.
    pub fn missed(&self) -> u64 {
        self.sent - self.answered
    }
}

/// Streams `count` poses from `pose_at(i)` at `rate_hz` (a tick per
/// `1 / rate_hz`, `per_tick` poses a tick, late ticks caught up), without
/// waiting for answers, and reads every answer; the k-th answer must carry
/// the k-th pose's sequence number.
/// Returns after the last answer or `timeout` after the last send.
pub async fn pipelined(
    client: &mut FissureClient<Channel>,
    instrument: &str,
    count: u64,
    rate_hz: f64,
    per_tick: u64,
    pose_at: impl Fn(u64) -> pb::PoseSample + Send + 'static,
    timeout: Duration,
) -> anyhow::Result<StreamReport> {
    let (tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(256);
    let req = fissure_cli::client::replay::haptic_request(
        tokio_stream::wrappers::ReceiverStream::new(rx),
        instrument,
        None,
    )?;
    let mut inbound = client.haptic(req).await?.into_inner();
    let sent_at = Arc::new(Mutex::new(Vec::<(Instant, u64)>::with_capacity(
        count as usize,
    )));
    let sent_at_w = sent_at.clone();
    let sender = tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate_hz));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        let mut i = 0;
        while i < count {
            tick.tick().await;
            for _ in 0..per_tick.min(count - i) {
                let p = pose_at(i);
                sent_at_w
                    .lock()
                    .expect("sent_at")
                    .push((Instant::now(), p.sequence));
                if tx.send(p).await.is_err() {
                    return (i, tx);
                }
                i += 1;
            }
        }
        (i, tx)
    });
    let mut report = StreamReport::default();
    let mut deadline: Option<tokio::time::Instant> = None;
    let mut sender = Some(sender);
    let mut keep_open = None;
    while report.answered < count {
        if let Some(s) = &sender {
            if s.is_finished() {
                let (sent, tx) = sender.take().expect("sender").await?;
                report.sent = sent;
                keep_open = Some(tx);
                deadline = Some(tokio::time::Instant::now() + timeout);
            }
        }
        let wait = match deadline {
            Some(d) => d.saturating_duration_since(tokio::time::Instant::now()),
            None => Duration::from_millis(100),
        };
        match tokio::time::timeout(wait, inbound.message()).await {
            Ok(Ok(Some(answer))) => {
                let k = report.answered as usize;
                let (at, expected) = sent_at.lock().expect("sent_at")[k];
                report.round_trip_us.push(at.elapsed().as_secs_f64() * 1e6);
                if answer.sequence != expected && report.bad_answers.len() < 10 {
                    report.bad_answers.push(format!(
                        "answer {k} has sequence {}, expected {expected}",
                        answer.sequence
                    ));
                }
                if let Some(r) = &answer.rejection {
                    report
                        .rejected
                        .push((answer.sequence, r.code, r.message.clone()));
                }
                let f = answer.force_n.unwrap_or_default();
                if !(f.x.is_finite() && f.y.is_finite() && f.z.is_finite())
                    && report.bad_answers.len() < 10
                {
                    report
                        .bad_answers
                        .push(format!("pose {}: non-finite force {f:?}", answer.sequence));
                }
                report.answered += 1;
                report.touching += u64::from(answer.contact_count > 0);
            }
            Ok(Ok(None)) => break,
            Ok(Err(status)) => anyhow::bail!("{instrument}: stream failed: {status}"),
            Err(_) if deadline.is_some() => break,
            Err(_) => {}
        }
    }
    if let Some(s) = sender.take() {
        let (sent, tx) = s.await?;
        report.sent = sent;
        keep_open = Some(tx);
    }
    // Close the stream and wait for the server to end it (the claim is
    // released then).
    drop(keep_open);
    let _ = tokio::time::timeout(Duration::from_secs(5), async {
        while let Ok(Some(_)) = inbound.message().await {}
    })
    .await;
    Ok(report)
}

/// A pose of an instrument with its handle at `(x, HANDLE_Y, z)`, face A down.
pub fn flat_pose(t_s: f64, sequence: u64, x: f64, z: f64) -> pb::PoseSample {
    fissure_tests::pose(t_s, sequence, [x, HANDLE_Y, z], FLAT_DOWN)
}

/// Pushing in and out: depth below the touch height at time `t`, m
/// (0 to `depth`, a 2 Hz cosine).
pub fn push_depth(t: f64, depth: f64) -> f64 {
    0.5 * depth * (1.0 - (2.0 * std::f64::consts::PI * 2.0 * t).cos())
}

/// Waits until `check` holds (polled every 20 ms) or `limit` passes.
pub async fn eventually(limit: Duration, mut check: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        if check() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    check()
}

/// The next frame of a watch stream, failing after 10 s.
pub async fn next_frame(
    watch: &mut tonic::Streaming<pb::DeformationFrame>,
) -> anyhow::Result<pb::DeformationFrame> {
    match tokio::time::timeout(Duration::from_secs(10), watch.message()).await {
        Ok(Ok(Some(f))) => Ok(f),
        Ok(Ok(None)) => anyhow::bail!("the watch stream ended"),
        Ok(Err(status)) => anyhow::bail!("the watch stream failed: {status}"),
        Err(_) => anyhow::bail!("no frame within 10 s"),
    }
}

/// The `fissure-server` binary: `FISSURE_SERVER_BIN` if set, else the one
/// of this build's profile (built on demand).
pub fn server_binary() -> PathBuf {
    if let Some(path) = std::env::var_os("FISSURE_SERVER_BIN") {
        return PathBuf::from(path);
    }
    let exe = std::env::current_exe().expect("test executable");
    let profile_dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("target/<profile>/deps");
    let bin = profile_dir.join("fissure-server");
    if !bin.exists() {
        let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") | None => "dev".to_owned(),
            Some(p) => p.to_owned(),
        };
        let status = Command::new(env!("CARGO"))
            .args([
                "build",
                "-p",
                "fissure-server",
                "--bin",
                "fissure-server",
                "--profile",
            ])
            .arg(&profile)
            .status()
            .expect("running cargo build");
        assert!(status.success(), "building fissure-server failed");
    }
    assert!(bin.exists(), "{} is missing", bin.display());
    bin
}
