//! Bad poses on a live haptic stream (cube scene, free-running): every bad
//! pose gets the answer documented in docs/reliability.md and the simulation
//! stays finite.
//!
//! * NaN or infinite values, a zero or non-unit quaternion (norm off by more
//!   than 1e-3), a missing field: rejected (`rejection.code` 3,
//!   INVALID_ARGUMENT, zero force), nothing applied, the stream stays open.
//! * A sequence number not increasing or a timestamp going back: rejected the
//!   same way (an equal timestamp with a larger sequence is accepted).
//! * A jump farther than the scene's `loops.max_jump_m` in one sample:
//!   applied (the instrument is where the device says it is) and flagged
//!   `SAFETY_FLAG_POSE_JUMP`; the force stays finite and within the scene's
//!   `max_force_n` (clamped and flagged above it).
//! * A flood (10 kHz from one client): answered in order, one answer a pose;
//!   above the stream budget (2 x `haptic_rate_hz` after a 1 s burst) poses
//!   are answered at once with RESOURCE_EXHAUSTED, nothing computed; the
//!   server keeps no queue of its own (HTTP/2 flow control pushes back on the
//!   sender), so memory stays flat and the other client keeps its rate.

use crate::reliability_common::*;
use fissure_engine::sim::{SimOptions, flags};
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use std::time::Duration;

const INVALID_ARGUMENT: i32 = 3;

fn force_of(s: &pb::ForceSample) -> [f64; 3] {
    let f = s.force_n.unwrap_or_default();
    [f.x, f.y, f.z]
}

fn assert_rejected(s: &pb::ForceSample, sequence: u64, field: &str) {
    let r = s
        .rejection
        .as_ref()
        .unwrap_or_else(|| panic!("pose {sequence} ({field}) was accepted: {s:?}"));
    assert_eq!(r.code, INVALID_ARGUMENT, "{r:?}");
    assert!(
        r.message.contains(field),
        "rejection of pose {sequence} does not name `{field}`: {}",
        r.message
    );
    assert_eq!(s.sequence, sequence, "the answer is for another pose");
    assert_eq!(force_of(s), [0.0; 3], "a rejected pose has zero force");
    assert_eq!(s.contact_count, 0);
}

/// Non-finite values, zero and non-unit quaternions and missing fields are
/// rejected with INVALID_ARGUMENT naming the field; the instrument stays at
/// the last accepted pose; the next valid pose is served; stats count them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invalid_values_are_rejected_and_change_nothing() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    // 1 mm above the top: accepted, no contact.
    let above = TOUCH_Z + 0.001;
    let ok = haptic.send(flat_pose(0.0, 1, LEFT_X, above)).await?;
    assert!(ok.rejection.is_none(), "{ok:?}");

    let nan = f64::NAN;
    let inf = f64::INFINITY;
    let p = [LEFT_X, HANDLE_Y, above];
    let bad: Vec<(&str, pb::PoseSample)> = vec![
        ("position_m.x", pose(0.001, 2, [nan, p[1], p[2]], FLAT_DOWN)),
        ("position_m.y", pose(0.001, 3, [p[0], inf, p[2]], FLAT_DOWN)),
        (
            "position_m.z",
            pose(0.001, 4, [p[0], p[1], -inf], FLAT_DOWN),
        ),
        ("t_s", pose(nan, 5, p, FLAT_DOWN)),
        ("t_s", pose(inf, 6, p, FLAT_DOWN)),
        ("orientation.w", pose(0.001, 7, p, [nan, 0.0, 0.0, 0.0])),
        ("orientation.z", pose(0.001, 8, p, [0.5, -0.5, 0.5, inf])),
        ("orientation", pose(0.001, 9, p, [0.0; 4])),
        ("orientation", pose(0.001, 10, p, [1.0, 1.0, 1.0, 1.0])),
        // Norm 1.002: outside the 1e-3 tolerance.
        ("orientation", pose(0.001, 11, p, [1.002, 0.0, 0.0, 0.0])),
        // Subnormal quaternion: its norm is 1e-310, not 1.
        ("orientation", pose(0.001, 12, p, [1e-310, 0.0, 0.0, 0.0])),
        (
            "orientation",
            pb::PoseSample {
                orientation: None,
                ..flat_pose(0.001, 13, LEFT_X, above)
            },
        ),
        (
            "position_m",
            pb::PoseSample {
                position_m: None,
                ..flat_pose(0.001, 14, LEFT_X, above)
            },
        ),
        // A pose far into the tissue with a NaN: nothing of it is applied.
        (
            "orientation.x",
            pose(0.001, 15, [p[0], p[1], 0.02], [0.5, nan, 0.5, 0.5]),
        ),
    ];
    for (field, msg) in &bad {
        let answer = haptic.send(*msg).await?;
        assert_rejected(&answer, msg.sequence, field);
    }
    // Nothing was applied: the latest frame (made after the accepted pose;
    // rejected poses do not make the deformation loop step) has the
    // instrument at the accepted pose, finite, and the tissue at rest.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let frame = next_frame(&mut watch).await?;
    let left = frame
        .instruments
        .iter()
        .find(|i| i.name == "left")
        .expect("left");
    let pos = left.position_m.expect("position");
    assert!(
        (pos.z - above).abs() < 1e-12,
        "left is at {pos:?}, not the accepted pose"
    );
    assert!(frame.positions_m.iter().all(|v| v.is_finite()));
    assert!(
        frame.max_displacement_m < 1e-9,
        "{}",
        frame.max_displacement_m
    );

    // Within the tolerance (norm 1.0005) is accepted and normalised.
    let near_unit = [0.5 * 1.0005, -0.5 * 1.0005, 0.5 * 1.0005, 0.5 * 1.0005];
    let answer = haptic.send(pose(0.002, 16, p, near_unit)).await?;
    assert!(answer.rejection.is_none(), "{answer:?}");
    // The stream is still served normally, into the tissue.
    let answer = haptic
        .send(flat_pose(0.003, 17, LEFT_X, TOUCH_Z - 0.001))
        .await?;
    assert!(answer.rejection.is_none(), "{answer:?}");
    assert!(answer.contact_count > 0, "{answer:?}");
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert_eq!(stats.rejected_poses, bad.len() as u64);
    assert_eq!(stats.force_samples, 3);
    haptic.close().await;
    server.stop().await
}

/// Sequence numbers must increase and timestamps must not go back; a
/// rejection leaves the last accepted pose as the reference.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn poses_going_back_are_rejected() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let z = TOUCH_Z + 0.001;
    let a = haptic.send(flat_pose(0.010, 5, LEFT_X, z)).await?;
    assert!(a.rejection.is_none());
    // Time back by 1 ms.
    let r = haptic.send(flat_pose(0.009, 6, LEFT_X, z)).await?;
    assert_rejected(&r, 6, "before the previous");
    // Time back by the smallest step.
    let r = haptic
        .send(flat_pose(0.010f64.next_down(), 7, LEFT_X, z))
        .await?;
    assert_rejected(&r, 7, "before the previous");
    // Sequence repeated, then going back.
    let r = haptic.send(flat_pose(0.011, 5, LEFT_X, z)).await?;
    assert_rejected(&r, 5, "does not follow 5");
    let r = haptic.send(flat_pose(0.011, 0, LEFT_X, z)).await?;
    assert_rejected(&r, 0, "does not follow 5");
    // Equal time, larger sequence (a device that repeats its clock): accepted.
    let r = haptic.send(flat_pose(0.010, 8, LEFT_X, z)).await?;
    assert!(r.rejection.is_none(), "{r:?}");
    // Gaps in sequence (lost packets upstream): accepted.
    let r = haptic.send(flat_pose(0.020, 100, LEFT_X, z)).await?;
    assert!(r.rejection.is_none(), "{r:?}");
    // The reference moved to the last accepted pose (t = 0.020, seq 100).
    let r = haptic.send(flat_pose(0.015, 101, LEFT_X, z)).await?;
    assert_rejected(&r, 101, "before the previous 0.02");
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert_eq!(stats.rejected_poses, 5);
    haptic.close().await;
    server.stop().await
}

/// A one-metre jump in one sample, out of the tissue, back in at depth, and
/// through the whole cube: applied and flagged POSE_JUMP; forces finite and
/// within `max_force_n` (8 N); frames finite; back home the tissue relaxes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_metre_jump_is_flagged_and_the_simulation_stays_finite() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let max_force = server.sim.scene().loops.max_force_n;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let mut seq = 0;
    let mut t = 0.0;
    let mut next = |x: f64, z: f64| {
        seq += 1;
        t += 1e-3;
        flat_pose(t, seq, x, z)
    };
    let depth = 0.003;
    // Into the tissue slowly (0.05 mm a sample), hold 100 ms.
    for i in 0..=160 {
        let z = TOUCH_Z + 0.001 - (0.00005 * i as f64).min(0.001 + depth);
        let s = haptic.send(next(LEFT_X, z)).await?;
        assert_eq!(s.safety_flags & flags::POSE_JUMP, 0, "{s:?}");
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let held = haptic.send(next(LEFT_X, TOUCH_Z - depth)).await?;
    assert!(held.contact_count > 0);
    let mut jumps = Vec::new();
    // 1 m sideways (out of the tissue), 1 m back at depth, 1 m down through
    // the whole cube, 1 m back up at depth.
    for (x, z) in [
        (LEFT_X + 1.0, TOUCH_Z - depth),
        (LEFT_X, TOUCH_Z - depth),
        (LEFT_X, TOUCH_Z - depth - 1.0),
        (LEFT_X, TOUCH_Z - depth),
    ] {
        let s = haptic.send(next(x, z)).await?;
        assert!(s.rejection.is_none(), "{s:?}");
        assert_ne!(
            s.safety_flags & flags::POSE_JUMP,
            0,
            "jump not flagged: {s:?}"
        );
        let f = force_of(&s);
        let norm = f.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(
            norm.is_finite() && norm <= max_force * (1.0 + 1e-12),
            "{s:?}"
        );
        jumps.push(s);
        // Let a deformation step see each pose.
        tokio::time::sleep(Duration::from_millis(60)).await;
    }
    assert_eq!(jumps[0].contact_count, 0, "1 m away there is no contact");
    // A jump into the tissue cannot be followed by the contact history (its
    // travel is far above the plate thickness): the far face may pair with
    // the fixed bottom and the deformation step fail. Whatever the steps did,
    // frames stay finite and a failed step keeps the last good state.
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let mut failed_frames = 0;
    for _ in 0..5 {
        let s = haptic.send(next(LEFT_X, TOUCH_Z - depth)).await?;
        assert_eq!(s.safety_flags & flags::POSE_JUMP, 0);
        assert!(force_of(&s).iter().all(|v| v.is_finite()));
        let f = next_frame(&mut watch).await?;
        assert!(
            f.positions_m.iter().all(|v| v.is_finite()),
            "frame {}",
            f.frame
        );
        assert!(f.max_displacement_m.is_finite() && f.max_displacement_m < 0.04);
        if !f.solver_error.is_empty() {
            failed_frames += 1;
            assert_ne!(s.safety_flags & flags::SOLVER_FAILED, 0);
        }
        tokio::time::sleep(Duration::from_millis(30)).await;
    }
    // Out of the tissue slowly; released, the instrument goes home and the
    // tissue relaxes to rest with successful steps.
    for i in 0..=100 {
        let z = TOUCH_Z - depth + 0.00005 * i as f64;
        haptic.send(next(LEFT_X, z)).await?;
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    haptic.close().await;
    let mut relaxed = false;
    for _ in 0..100 {
        let f = next_frame(&mut watch).await?;
        if f.max_displacement_m < 1e-9 && f.solver_error.is_empty() {
            relaxed = true;
            break;
        }
    }
    eprintln!("one-metre jumps: {failed_frames} of 5 frames at depth after them had a failed step");
    assert!(relaxed, "the tissue did not return to rest");
    server.stop().await
}

/// One client floods 10,000 poses at 10 kHz while the other streams at 1 kHz.
/// Every pose of both is answered once, in order. The flood is served at
/// most at the stream rate limit (2 kHz sustained after a burst of 2000) and
/// the poses above it are answered at once with RESOURCE_EXHAUSTED (where
/// the machine serves it more slowly than that, nothing is refused and the
/// flood is paced by HTTP/2 flow control instead); the 1 kHz client
/// gets no rejection, its median round trip stays close to what it is
/// without the flood (measured first, side by side) and none of its answers
/// is held back long; process memory stays flat.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_10_khz_flood_is_rate_limited_and_does_not_starve_the_other_client() -> anyhow::Result<()>
{
    let _alone = crate::alone().await;
    const RESOURCE_EXHAUSTED: i32 = 8;
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut flood_client = own_connection(&server.url).await?;
    let mut paced_client = own_connection(&server.url).await?;
    let paced_pose = |offset: u64| {
        move |i: u64| {
            let t = (i + offset) as f64 * 1e-3;
            flat_pose(t, i + 1 + offset, RIGHT_X, TOUCH_Z - push_depth(t, 0.002))
        }
    };
    // Baseline: the 1 kHz client alone.
    let alone = pipelined(
        &mut paced_client,
        "right",
        1000,
        1000.0,
        1,
        paced_pose(0),
        Duration::from_secs(10),
    )
    .await?;
    assert_eq!(alone.missed(), 0);
    let p99_alone = quantile(&mut alone.round_trip_us.clone(), 0.99);
    let rss0 = rss_bytes();
    let started = std::time::Instant::now();
    let flood = tokio::spawn(async move {
        // 10 poses every 1 ms tick: 10 kHz.
        pipelined(
            &mut flood_client,
            "left",
            10_000,
            1000.0,
            10,
            |i| {
                let t = i as f64 * 1e-4;
                flat_pose(t, i + 1, LEFT_X, TOUCH_Z - push_depth(t, 0.002))
            },
            Duration::from_secs(30),
        )
        .await
    });
    let paced = pipelined(
        &mut paced_client,
        "right",
        1000,
        1000.0,
        1,
        paced_pose(1000),
        Duration::from_secs(10),
    )
    .await?;
    let flood = flood.await??;
    let flood_s = started.elapsed().as_secs_f64();
    let rss1 = rss_bytes();
    assert_eq!(flood.sent, 10_000);
    assert_eq!(
        flood.missed(),
        0,
        "flood: {} poses unanswered",
        flood.missed()
    );
    assert!(flood.bad_answers.is_empty(), "{:?}", &flood.bad_answers[..]);
    assert!(
        flood
            .rejected
            .iter()
            .all(|(_, code, m)| *code == RESOURCE_EXHAUSTED && m.contains("pose rate above")),
        "{:?}",
        flood.rejected.first()
    );
    let served = flood.sent - flood.rejected.len() as u64;
    // At most the sustained rate over the run plus the burst (2000 / s, 2000).
    assert!(
        (served as f64) <= 2000.0 * flood_s + 2000.0 + 1.0,
        "{served} flood poses served in {flood_s:.2} s"
    );
    assert!(served >= 2000, "the flood was not served ({served})");
    assert_eq!(paced.sent, 1000);
    assert_eq!(paced.missed(), 0, "paced: {} unanswered", paced.missed());
    assert!(paced.bad_answers.is_empty(), "{:?}", &paced.bad_answers[..]);
    assert!(paced.rejected.is_empty(), "{:?}", paced.rejected.first());
    assert!(
        paced.touching > 0,
        "the paced client never touched the tissue"
    );
    let p99 = quantile(&mut paced.round_trip_us.clone(), 0.99);
    let p50_alone = quantile(&mut alone.round_trip_us.clone(), 0.5);
    let p50 = quantile(&mut paced.round_trip_us.clone(), 0.5);
    eprintln!(
        "flood: 10000 poses at 10 kHz answered in {flood_s:.2} s, {served} served, {} \
         rejected (RESOURCE_EXHAUSTED); 1 kHz client round trip p50 {p50_alone:.0} us, p99 \
         {p99_alone:.0} us alone, p50 {p50:.0} us, p99 {p99:.0} us beside the flood; RSS \
         {:.1} -> {:.1} MiB",
        flood.rejected.len(),
        rss0 as f64 / 1048576.0,
        rss1 as f64 / 1048576.0
    );
    // Not starved: beside the flood the paced client's median round trip
    // stays within 4 times the one measured alone plus 5 ms, and no answer
    // waits a quarter of the run. (Its p99 is printed, not bounded: while
    // the flood's burst is served at its full 10 kHz, a loaded 2-core
    // machine running the debug build serves both clients, the deformation
    // loop and the in-process client runtime from the core left, and the
    // paced answers then wait tens of milliseconds; `fissure bench loop`
    // measures the release build's tail.)
    let worst = paced.round_trip_us.iter().copied().fold(0.0, f64::max);
    assert!(
        p50 < 4.0 * p50_alone + 5_000.0,
        "paced median round trip {p50:.0} us beside the flood, {p50_alone:.0} us alone"
    );
    assert!(
        worst < 250_000.0,
        "a paced answer waited {worst:.0} us beside the flood (p99 {p99:.0} us)"
    );
    assert!(
        rss1 < rss0 + 64 * 1024 * 1024,
        "RSS grew {} MiB",
        (rss1 - rss0) >> 20
    );
    server.stop().await
}
