//! Watchers that never read: no memory growth, the others unaffected. Alone
//! in its test binary: it measures the process's resident memory, which
//! tests running beside it would disturb.

mod reliability_common;

use fissure_proto::v1 as pb;
use fissure_server::service::ServeOptions;
use fissure_server::sim::SimOptions;
use fissure_tests::TestServer;
use reliability_common::*;
use std::time::{Duration, Instant};

/// Sixteen watchers that never read, each on its own connection (64 KiB
/// receive windows, so that what they do not read stays on the server side),
/// while the tissue is pushed for 4 s on a 16-cell cube (~19 kB a frame, ~50
/// frames a second): process memory is flat (under 6 MiB over the last 2 s;
/// a queue per watcher would add 14 MB a second), the haptic client misses no
/// sample, and a watcher that reads keeps getting frames (latest-wins: at
/// least one in five on this loaded 2-core machine).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watchers_that_never_read_do_not_grow_memory() -> anyhow::Result<()> {
    let scene = cube_scene(&[("cells = 8", "cells = 16")]);
    let options = SimOptions {
        max_watchers: 17,
        ..SimOptions::default()
    };
    let server = TestServer::start_scene(scene, options, ServeOptions::default()).await?;
    let mut stalled = Vec::new();
    for _ in 0..16 {
        let mut c = small_window_connection(&server.url).await?;
        let s = c
            .watch(pb::WatchRequest {
                include_positions: true,
            })
            .await?
            .into_inner();
        // Holding the stream and the client without ever reading.
        stalled.push((c, s));
    }
    let mut reader_client = own_connection(&server.url).await?;
    let mut reader = reader_client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    // It reads until the measured run is over (the warm-up alone takes 4 s).
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop_reading = stop.clone();
    let reading = tokio::spawn(async move {
        let mut frames = Vec::new();
        let end = Instant::now() + Duration::from_secs(30);
        while Instant::now() < end && !stop_reading.load(std::sync::atomic::Ordering::Relaxed) {
            match tokio::time::timeout(Duration::from_millis(500), reader.message()).await {
                Ok(Ok(Some(f))) => frames.push((f.frame, f.positions_m.len())),
                Ok(_) => break,
                Err(_) => {}
            }
        }
        frames
    });
    let sim = server.sim.clone();
    assert!(eventually(Duration::from_secs(2), || sim.stats().watchers == 17).await);
    let mut haptic_client = own_connection(&server.url).await?;
    // Warm-up: the whole push once fills the buffers and the engine's
    // caches (the compliance columns of every node the press reaches and
    // of the band ahead of it, computed in the background).
    let warm = pipelined(
        &mut haptic_client,
        "left",
        4000,
        1000.0,
        1,
        |i| {
            let t = i as f64 * 1e-3;
            flat_pose(t, i + 1, LEFT_X, TOUCH_Z - push_depth(t, 0.003))
        },
        Duration::from_secs(10),
    )
    .await?;
    assert_eq!(warm.missed(), 0);
    assert!(warm.rejected.is_empty(), "{:?}", warm.rejected);
    let frame0 = server.sim.snapshot().frame;
    let rss0 = rss_bytes();
    // RSS every 0.5 s during the run.
    let sampler = tokio::spawn(async {
        let mut samples = Vec::new();
        for _ in 0..8 {
            tokio::time::sleep(Duration::from_millis(500)).await;
            samples.push(rss_bytes());
        }
        samples
    });
    let run = pipelined(
        &mut haptic_client,
        "left",
        4000,
        1000.0,
        1,
        |i| {
            let t = i as f64 * 1e-3;
            flat_pose(t, i + 1, LEFT_X, TOUCH_Z - push_depth(t, 0.003))
        },
        Duration::from_secs(10),
    )
    .await?;
    let rss1 = rss_bytes();
    let frame1 = server.sim.snapshot().frame;
    let samples = sampler.await?;
    // Growth over the second half of the run (2 s): a queue per stalled
    // watcher would add 16 x 50 x 18 kB = 14 MB a second, linearly.
    let mid = samples[3];
    let late_growth = rss1.saturating_sub(mid);
    assert_eq!(run.missed(), 0, "the haptic client missed samples");
    assert!(run.bad_answers.is_empty(), "{:?}", run.bad_answers);
    assert!(run.rejected.is_empty(), "{:?}", run.rejected);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let frames = reading.await?;
    let surface_values = 3 * server.sim.model().rest_surface.len();
    assert!(frames.iter().all(|&(_, n)| n == surface_values));
    let seen = frames
        .iter()
        .filter(|&&(f, _)| f > frame0 && f <= frame1)
        .count() as u64;
    let published = frame1 - frame0;
    eprintln!(
        "stalled watchers: RSS {:.1} -> {:.1} (after 2 s) -> {:.1} MiB over {published} \
         frames of {} kB; the reading watcher saw {seen}",
        rss0 as f64 / 1048576.0,
        mid as f64 / 1048576.0,
        rss1 as f64 / 1048576.0,
        surface_values * 4 / 1000
    );
    assert!(published > 50, "only {published} frames in 4 s");
    assert!(
        seen * 5 >= published,
        "the reading watcher saw {seen} of {published} frames"
    );
    // Flat: under 6 MiB in the last 2 s, and under 48 MiB in all (the
    // engine's workspaces and the allocator's arenas settle in the first
    // seconds whatever the watchers do).
    assert!(
        late_growth < 6 * 1024 * 1024,
        "RSS grew {} MiB in the last 2 s with stalled watchers",
        late_growth >> 20
    );
    assert!(
        rss1 < rss0 + 48 * 1024 * 1024,
        "RSS grew {} MiB with stalled watchers",
        (rss1 - rss0) >> 20
    );
    drop(stalled);
    server.stop().await
}
