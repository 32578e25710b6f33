//! Watchers that never read: no memory growth, the others unaffected. In the
//! `isolated` test binary, alone in the process while it runs: it measures
//! the process's resident memory, which tests running beside it would disturb.

use crate::reliability_common::*;
use fissure_engine::sim::{Mode, SimOptions};
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_tests::TestServer;
use std::time::{Duration, Instant};

/// Sixteen watchers that never read, each on its own connection (64 KiB
/// receive windows, so that what they do not read stays on the server side),
/// while the tissue is pushed for 4 s on a 16-cell cube (~19 kB a frame, ~50
/// frames a second): process memory is flat (under 6 MiB over the last 2 s
/// beyond what the solver's compliance cache added, as `GetStats` reports
/// it; a queue per watcher would add 14 MB a second), the haptic client misses no
/// sample, and a watcher that reads keeps getting frames (latest-wins: at
/// least one in five on this loaded 2-core machine).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watchers_that_never_read_do_not_grow_memory() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let scene = cube_scene(&[("cells = 8", "cells = 16")]);
    // Stepped: the run below replays the warm-up's poses one period of the
    // push later, so its steps are the warm-up's and reach no tissue the
    // warm-up did not (compliance columns are computed in the step, not in
    // the background): whatever memory the engine needs it has before the
    // measured run, however loaded the machine.
    let options = SimOptions {
        max_watchers: 17,
        mode: Some(Mode::Stepped { clients: 1 }),
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
    // It reads until the measured run is over (the warm-up alone takes 4 s,
    // more on a loaded machine, where the stepped runner falls behind the
    // clock; the bound only keeps a broken test from hanging).
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop_reading = stop.clone();
    let reading = tokio::spawn(async move {
        let mut frames = Vec::new();
        let end = Instant::now() + Duration::from_secs(600);
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
    // caches (the compliance columns of every node the press reaches).
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
        // The first contact computes its columns in the step: tens of
        // seconds on a loaded machine.
        Duration::from_secs(120),
    )
    .await?;
    assert_eq!(warm.missed(), 0);
    assert!(warm.rejected.is_empty(), "{:?}", warm.rejected);
    let frame0 = server.sim.snapshot().frame;
    let rss0 = rss_bytes();
    // RSS every 0.5 s during the run, with the solver's cache at the same
    // moments: were contact to reach new tissue, the compliance columns it
    // adds would be the engine's growth, not the watchers'.
    let cache_of = server.sim.clone();
    let cache0 = server.sim.stats().solver_cache_bytes;
    let sampler = tokio::spawn(async move {
        let mut samples = Vec::new();
        for _ in 0..8 {
            tokio::time::sleep(Duration::from_millis(500)).await;
            samples.push((rss_bytes(), cache_of.stats().solver_cache_bytes));
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
            // The warm-up's poses 4 s (8 periods of the push) later.
            let t = 4.0 + i as f64 * 1e-3;
            flat_pose(t, i + 1, LEFT_X, TOUCH_Z - push_depth(t, 0.003))
        },
        // Every answer must come; on a loaded machine they come late.
        Duration::from_secs(60),
    )
    .await?;
    let rss1 = rss_bytes();
    let cache1 = server.sim.stats().solver_cache_bytes;
    let frame1 = server.sim.snapshot().frame;
    let samples = sampler.await?;
    // Growth over the second half of the run (2 s), less the solver cache's:
    // a queue per stalled watcher would add 16 x 50 x 18 kB = 14 MB a
    // second, linearly.
    let (mid, cache_mid) = samples[3];
    assert!(cache0 > 0, "the warm-up press cached no compliance column");
    let late_growth = rss1
        .saturating_sub(mid)
        .saturating_sub(cache1.saturating_sub(cache_mid));
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
    let mib = |b: u64| b as f64 / 1048576.0;
    eprintln!(
        "stalled watchers: RSS {:.1} -> {:.1} (after 2 s) -> {:.1} MiB, the solver's cache \
         {:.1} -> {:.1} -> {:.1} MiB, over {published} frames of {} kB; the reading watcher \
         saw {seen}",
        mib(rss0),
        mib(mid),
        mib(rss1),
        mib(cache0),
        mib(cache_mid),
        mib(cache1),
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
        "RSS grew {} MiB in the last 2 s with stalled watchers, beyond the solver cache's growth",
        late_growth >> 20
    );
    let growth = rss1
        .saturating_sub(rss0)
        .saturating_sub(cache1.saturating_sub(cache0));
    assert!(
        growth < 48 * 1024 * 1024,
        "RSS grew {} MiB with stalled watchers, beyond the solver cache's growth",
        growth >> 20
    );
    drop(stalled);
    server.stop().await
}
