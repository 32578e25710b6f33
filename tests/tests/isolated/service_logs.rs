//! What the server says in its log, read through a subscriber installed for
//! this test process: a haptic client that stops reading (its stream ends,
//! its connection does not), a deformation loop behind its interval (warned
//! once), and the stages of loading a scene.

use crate::raw_h2;

use crate::reliability_common::{FLAT_DOWN, HANDLE_Y, LEFT_X, TOUCH_Z, cube_scene};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_proto::v1 as pb;
use fissure_server::{MAX_UNREAD_ANSWERS, ServeOptions};
use fissure_tests::{Haptic, TestServer, pose, wait_until_claimed};
use std::io::Write;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

/// Everything logged by this process since it started (info and up).
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

fn log() -> &'static Captured {
    static LOG: OnceLock<Captured> = OnceLock::new();
    LOG.get_or_init(|| {
        let captured = Captured::default();
        let writer = captured.clone();
        tracing_subscriber::fmt()
            .with_env_filter("info")
            .with_ansi(false)
            .with_writer(move || writer.clone())
            .init();
        captured
    })
}

fn lines_with(pattern: &str) -> Vec<String> {
    let text = String::from_utf8_lossy(&log().0.lock().unwrap()).into_owned();
    text.lines()
        .filter(|l| l.contains(pattern))
        .map(str::to_owned)
        .collect()
}

/// A client (64 KiB stream window) sends poses at 1 kHz and reads none of
/// the answers for 4 s. Once its window and the transport's buffers are full
/// (about 1,500 answers of 90 bytes) and `MAX_UNREAD_ANSWERS` more are queued
/// unread for `UNREAD_GRACE` (about 3 s in), its stream ends: when it reads again it gets the answers queued, in order, then
/// RESOURCE_EXHAUSTED (8) saying it did not read; the server logs a warning
/// naming the instrument; the instrument is released; the connection keeps
/// serving, a unary call during the stall and a new claim after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_stops_reading_loses_its_stream_not_its_connection() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    log();
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut conn = raw_h2::connect(server.addr).await?;
    let (resp, mut stream) =
        raw_h2::call(&mut conn, "Haptic", &[("fissure-instrument", "left")], None).await?;
    let above = [LEFT_X, HANDLE_Y, TOUCH_Z + 0.001];
    let sender = tokio::spawn(async move {
        let start = Instant::now();
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        let mut k = 0u64;
        while start.elapsed() < Duration::from_secs(4) {
            tick.tick().await;
            let msg = raw_h2::frame(&pose((k + 1) as f64 * 1e-3, k + 1, above, FLAT_DOWN));
            // Only what the server's window takes (it stops reading once the
            // stream has ended).
            stream.reserve_capacity(msg.len());
            let room = tokio::time::timeout(
                Duration::from_secs(1),
                futures::future::poll_fn(|cx| stream.poll_capacity(cx)),
            )
            .await;
            match room {
                Ok(Some(Ok(n))) if n >= msg.len() => {}
                _ => break,
            }
            if stream.send_data(msg, false).is_err() {
                break;
            }
            k += 1;
        }
        (k, stream)
    });
    tokio::time::sleep(Duration::from_millis(3_800)).await;
    // During the stall, the same connection serves a unary call.
    let (stats_resp, _s) = raw_h2::call(
        &mut conn,
        "GetStats",
        &[],
        Some(raw_h2::frame(&pb::GetStatsRequest {})),
    )
    .await?;
    let stats: pb::Stats = raw_h2::Reader::new(stats_resp)
        .await?
        .next()
        .await
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    assert!(stats.force_samples > MAX_UNREAD_ANSWERS as u64, "{stats:?}");
    assert!(stats.claimed.is_empty(), "released: {stats:?}");
    let (sent, _stream) = sender.await?;
    assert!(sent > MAX_UNREAD_ANSWERS as u64, "{sent} poses sent");
    // Reading again: the queued answers in order, then the status.
    let mut answers = raw_h2::Reader::new(resp).await?;
    let mut read = 0u64;
    let (code, message) = loop {
        match answers.next::<pb::ForceSample>().await {
            Ok(a) => {
                read += 1;
                assert_eq!(a.sequence, read, "answers in order");
                assert!(a.rejection.is_none());
            }
            Err(end) => break end,
        }
    };
    eprintln!(
        "stopped reading: {sent} poses sent in 4 s, {} force samples computed at 3.8 s, \
         {read} answers read after the stall, then status {code}",
        stats.force_samples
    );
    assert_eq!(code, tonic::Code::ResourceExhausted as i32, "{message}");
    assert!(
        message.contains("not read") && message.contains("left"),
        "{message}"
    );
    assert!(
        read >= MAX_UNREAD_ANSWERS as u64 && read <= sent,
        "{read} answers read of {sent} poses"
    );
    let warned = lines_with("stopped reading its force samples");
    assert_eq!(warned.len(), 1, "{warned:?}");
    assert!(
        warned[0].contains("WARN") && warned[0].contains("instrument=left"),
        "{warned:?}"
    );
    // The connection claims again, through the usual client too.
    let (resp, mut stream) =
        raw_h2::call(&mut conn, "Haptic", &[("fissure-instrument", "left")], None).await?;
    stream.send_data(raw_h2::frame(&pose(0.0, 1, above, FLAT_DOWN)), true)?;
    let mut again = raw_h2::Reader::new(resp).await?;
    let a: pb::ForceSample = again.next().await.map_err(|e| anyhow::anyhow!("{e:?}"))?;
    assert!(a.rejection.is_none() && a.sequence == 1);
    assert_eq!(
        again.next::<pb::ForceSample>().await.unwrap_err().0,
        0,
        "OK at the end"
    );
    let mut client = server.client().await?;
    assert_eq!(
        wait_until_claimed(&mut client, &[]).await?,
        Vec::<String>::new()
    );
    let mut h = Haptic::open(&mut client, "left", None).await?;
    assert!(
        h.send(pose(0.0, 1, above, FLAT_DOWN))
            .await?
            .rejection
            .is_none()
    );
    h.close().await;
    server.stop().await
}

/// A scene whose interval (0.5 ms) no step of a 12-cell cube can keep: the server
/// warns once that the loop is behind, naming the step time and the
/// interval, however long the session goes on; the loading stages come
/// first, in order, with the scene's name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_loop_behind_its_interval_is_warned_once_and_loading_reports_its_stages()
-> anyhow::Result<()> {
    let _alone = crate::alone().await;
    log();
    // 12 cells an edge: a step of about a millisecond or more here, never
    // under the interval (the 8-cell cube's can be).
    let scene = cube_scene(&[
        ("name = \"cube\"", "name = \"cube-fast-interval\""),
        ("cells = 8", "cells = 12"),
        (
            "deformation_interval_s = 0.02",
            "deformation_interval_s = 0.0005",
        ),
    ]);
    let server =
        TestServer::start_scene(scene, SimOptions::default(), ServeOptions::default()).await?;
    let stages = lines_with("scene cube-fast-interval");
    let expect = [
        "scene cube-fast-interval: building the model",
        "scene cube-fast-interval: setting up the compliance solver (2197 nodes, 10368 tetrahedra)",
        "scene cube-fast-interval loaded in",
    ];
    assert_eq!(stages.len(), expect.len(), "{stages:?}");
    for (line, want) in stages.iter().zip(expect) {
        assert!(
            line.contains(want) && line.contains("fissure::progress"),
            "{line:?} vs {want:?}"
        );
    }
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let start = Instant::now();
    let mut k = 0u64;
    while start.elapsed() < Duration::from_secs(3) {
        k += 1;
        // A slow press: every pose changes, so steps run back to back.
        let z = TOUCH_Z - 0.002 * (start.elapsed().as_secs_f64() / 3.0);
        haptic
            .send(pose(k as f64 * 1e-3, k, [LEFT_X, HANDLE_Y, z], FLAT_DOWN))
            .await?;
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    haptic.close().await;
    server.stop().await?;
    let warned: Vec<String> = lines_with("the deformation loop is behind its interval")
        .into_iter()
        .filter(|l| l.contains("scene=cube-fast-interval"))
        .collect();
    assert_eq!(warned.len(), 1, "{warned:?}");
    assert!(
        warned[0].contains("WARN")
            && warned[0].contains("loops.deformation_interval_s = 0.5 ms")
            && warned[0].contains("frames come less often"),
        "{warned:?}"
    );
    Ok(())
}

/// Stepped mode: a replay sent as fast as it is answered, on a scene whose
/// interval (0.5 ms of pose time a step) no step of a 12-cell cube keeps up with
/// in wall-clock time. The server warns once that the loop is behind and
/// how much slower than real time the replay runs at least (the median step
/// over the interval; the replay measured here is slower still, its round
/// trips and collision added).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stepped_replay_slower_than_real_time_is_warned_once_with_its_ratio() -> anyhow::Result<()>
{
    let _alone = crate::alone().await;
    log();
    let scene = cube_scene(&[
        ("name = \"cube\"", "name = \"cube-stepped-behind\""),
        ("cells = 8", "cells = 12"),
        (
            "deformation_interval_s = 0.02",
            "deformation_interval_s = 0.0005",
        ),
    ]);
    let options = SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    };
    let server = TestServer::start_scene(scene, options, ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let start = Instant::now();
    let mut k = 0u64;
    while start.elapsed() < Duration::from_secs(3) {
        k += 1;
        // A press 1 mm deep over 1 s of pose time, then held.
        let depth = 0.001 * (k as f64 * 1e-3).min(1.0);
        let z = TOUCH_Z + 0.0005 - depth;
        let a = haptic
            .send(pose(k as f64 * 1e-3, k, [LEFT_X, HANDLE_Y, z], FLAT_DOWN))
            .await?;
        assert!(a.rejection.is_none(), "{:?}", a.rejection);
    }
    let pose_time_s = k as f64 * 1e-3;
    let wall_s = start.elapsed().as_secs_f64();
    haptic.close().await;
    server.stop().await?;
    let warned: Vec<String> = lines_with("the deformation loop is behind its interval")
        .into_iter()
        .filter(|l| l.contains("scene=cube-stepped-behind"))
        .collect();
    assert_eq!(
        warned.len(),
        1,
        "{pose_time_s:.3} s of poses in {wall_s:.2} s: {warned:?}"
    );
    assert!(
        warned[0].contains("WARN")
            && warned[0].contains("loops.deformation_interval_s = 0.5 ms")
            && warned[0].contains("x slower than real time"),
        "{warned:?}"
    );
    // The steps are part of the replay's wall-clock time: the ratio named
    // is at most the measured one, within the spread of the step times
    // (the median of the three slow steps seen).
    let ratio: f64 = warned[0]
        .split("stepped replays run at least ")
        .nth(1)
        .and_then(|r| r.split('x').next())
        .and_then(|r| r.parse().ok())
        .expect("a ratio in the warning");
    let measured = wall_s / pose_time_s;
    eprintln!("stepped replay: warned {ratio}x, measured {measured:.1}x slower than real time");
    assert!(
        ratio > 1.0 && ratio < 3.0 * measured,
        "{ratio} vs {measured}"
    );
    Ok(())
}
