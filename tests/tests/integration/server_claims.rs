//! Instrument claims over gRPC on the `cube` scene: exclusive, released when the
//! stream ends (cleanly or by a client that vanishes), and clear statuses for a
//! third client and for unknown instruments.

use fissure_engine::sim::SimOptions;
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose, wait_until_claimed};
use std::time::Duration;

/// Lays the plate flat, face A down, tip towards +y (see cube.toml).
const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Home positions of the cube scene's instruments, m.
const LEFT_HOME: [f64; 3] = [0.011, 0.005, 0.04275];
const RIGHT_HOME: [f64; 3] = [0.029, 0.005, 0.04275];

async fn cube() -> anyhow::Result<TestServer> {
    TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await
}

/// A claim ends with its stream: after a clean close the server lists the
/// instrument as free and a new client on a new connection claims it and is
/// served from sequence 1 again (the old stream's sequence numbers do not carry
/// over).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn claim_released_when_stream_ends() -> anyhow::Result<()> {
    let server = cube().await?;
    let mut client = server.client().await?;
    let mut first = Haptic::open(&mut client, "left", None).await?;
    for i in 1..=5u64 {
        let s = first
            .send(pose(i as f64 * 1e-3, i, LEFT_HOME, FLAT_DOWN))
            .await?;
        assert!(s.rejection.is_none(), "{:?}", s.rejection);
    }
    assert_eq!(
        wait_until_claimed(&mut client, &["left"]).await?,
        vec!["left"]
    );
    first.close().await;
    assert!(wait_until_claimed(&mut client, &[]).await?.is_empty());

    let mut other = server.client().await?;
    let mut second = Haptic::open(&mut other, "left", None).await?;
    let s = second.send(pose(0.0, 1, LEFT_HOME, FLAT_DOWN)).await?;
    assert!(
        s.rejection.is_none(),
        "a new claim must not inherit the old stream's sequence: {:?}",
        s.rejection
    );
    assert_eq!(s.sequence, 1);
    second.close().await;
    server.stop().await
}

/// A client that disappears mid-stream (its channel, request stream and
/// response stream dropped without a clean end) loses its claim; a new client
/// then claims the instrument. The other instrument's client is not disturbed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disconnect_mid_stream_releases_claim_for_a_new_client() -> anyhow::Result<()> {
    let server = cube().await?;
    let mut observer = server.client().await?;
    let mut steady_client = server.client().await?;
    let mut steady = Haptic::open(&mut steady_client, "right", None).await?;
    {
        // Its own connection, so dropping it tears the connection down.
        let mut doomed_client = server.client().await?;
        let mut doomed = Haptic::open(&mut doomed_client, "left", None).await?;
        for i in 1..=20u64 {
            doomed
                .send(pose(i as f64 * 1e-3, i, LEFT_HOME, FLAT_DOWN))
                .await?;
        }
        // One more pose in flight when the client vanishes.
        doomed.push(pose(0.021, 21, LEFT_HOME, FLAT_DOWN)).await?;
        drop(doomed);
        drop(doomed_client);
    }
    let claimed = wait_until_claimed(&mut observer, &["right"]).await?;
    assert_eq!(claimed, vec!["right"], "left was not released");

    let mut new_client = server.client().await?;
    let mut reclaimed = Haptic::open(&mut new_client, "left", None).await?;
    let s = reclaimed.send(pose(0.0, 1, LEFT_HOME, FLAT_DOWN)).await?;
    assert!(s.rejection.is_none(), "{:?}", s.rejection);
    // The steady client kept its claim and is still served, in order.
    for i in 1..=5u64 {
        let s = steady
            .send(pose(i as f64 * 1e-3, i, RIGHT_HOME, FLAT_DOWN))
            .await?;
        assert!(s.rejection.is_none(), "{:?}", s.rejection);
        assert_eq!(s.sequence, i);
    }
    assert_eq!(
        wait_until_claimed(&mut observer, &["left", "right"]).await?,
        vec!["left", "right"]
    );
    reclaimed.close().await;
    steady.close().await;
    server.stop().await
}

/// With both instruments held, a third haptic client gets ALREADY_EXISTS for
/// either one, naming it; an unknown instrument is NOT_FOUND and lists the
/// scene's instruments; a claim without the instrument metadata is
/// INVALID_ARGUMENT. None of the failed claims disturbs the holders.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn third_client_and_unknown_instrument_get_clear_statuses() -> anyhow::Result<()> {
    let server = cube().await?;
    let mut a = server.client().await?;
    let mut b = server.client().await?;
    let mut left = Haptic::open(&mut a, "left", None).await?;
    let mut right = Haptic::open(&mut b, "right", None).await?;

    let mut third = server.client().await?;
    for name in ["left", "right"] {
        let err = Haptic::open(&mut third, name, None).await.unwrap_err();
        assert_eq!(err.code(), tonic::Code::AlreadyExists, "{name}: {err}");
        assert!(
            err.message().contains(&format!("{name:?}")),
            "the status should name {name}: {err}"
        );
    }
    let err = Haptic::open(&mut third, "centre", None).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::NotFound, "{err}");
    assert!(
        err.message().contains("\"centre\"") && err.message().contains("left, right"),
        "{err}"
    );
    // No instrument metadata at all.
    let (_tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(1);
    let err = third
        .haptic(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument, "{err}");
    assert!(err.message().contains("fissure-instrument"), "{err}");

    // The holders are still served.
    let l = left.send(pose(0.0, 1, LEFT_HOME, FLAT_DOWN)).await?;
    let r = right.send(pose(0.0, 1, RIGHT_HOME, FLAT_DOWN)).await?;
    assert!(l.rejection.is_none() && r.rejection.is_none());
    let stats = a.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert_eq!(stats.claimed, vec!["left", "right"]);
    assert_eq!(stats.force_samples, 2);
    left.close().await;
    right.close().await;
    // Released: the third client may now claim.
    let again = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            match Haptic::open(&mut third, "left", None).await {
                Ok(h) => return Ok(h),
                Err(e) if e.code() == tonic::Code::AlreadyExists => {
                    tokio::time::sleep(Duration::from_millis(10)).await
                }
                Err(e) => return Err(e),
            }
        }
    })
    .await??;
    again.close().await;
    server.stop().await
}
