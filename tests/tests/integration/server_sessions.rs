//! Sessions one after another on one server: `Reset` starts a stepped
//! session's clock afresh, a pose behind the clock is refused with a status
//! that says why, and frame numbers increase for the life of the server, in
//! the stream and in recordings.

use crate::reliability_common::{FLAT_DOWN, HANDLE_Y, LEFT_X, TOUCH_Z};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_proto::recording;
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_server::recording::ToFile;
use fissure_tests::{Haptic, TestServer, pose};

/// Handle position at sample `i` of a 200-sample press: from 1 mm above the
/// cube's top to 1 mm into it.
fn press(i: usize) -> [f64; 3] {
    let s = i as f64 / 199.0;
    [LEFT_X, HANDLE_Y, TOUCH_Z + 0.001 - 0.002 * s]
}

/// One press session of `left` at 1 kHz with timestamps from `t0_s`.
async fn press_session(
    client: &mut fissure_proto::v1::fissure_client::FissureClient<tonic::transport::Channel>,
    t0_s: f64,
) -> anyhow::Result<Vec<pb::ForceSample>> {
    let mut h = Haptic::open(client, "left", None).await?;
    let mut out = Vec::with_capacity(200);
    for i in 0..200 {
        out.push(
            h.send(pose(t0_s + i as f64 * 1e-3, i as u64, press(i), FLAT_DOWN))
                .await?,
        );
    }
    h.close().await;
    Ok(out)
}

/// Stepped mode: a second session whose timestamps start at 0 again is
/// refused until `Reset` (OUT_OF_RANGE, naming the clock), and after it runs
/// exactly as the first did: the same deformation steps, the same force on
/// every sample to the bit, frames numbered after the reset's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reset_restarts_the_stepped_clock_and_a_pose_behind_it_is_refused() -> anyhow::Result<()> {
    let options = SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    };
    let server = TestServer::start("cube", options, ServeOptions::default()).await?;
    let mut client = server.client().await?;

    let first = press_session(&mut client, 0.0).await?;
    let last = first.last().expect("answers");
    assert!(last.rejection.is_none(), "{last:?}");
    let push = last.force_n.expect("force").z;
    assert!(push > 1e-3, "1 mm into the cube: push {push} N");
    assert!(
        first.iter().any(|s| s.model_frame > 0),
        "no deformation step in the first session"
    );

    // The clock stands at 0.199 s: a new session from 0 would change the past.
    let mut h = Haptic::open(&mut client, "left", None).await?;
    let refused = h.send(pose(0.0, 0, press(0), FLAT_DOWN)).await?;
    h.close().await;
    let why = refused
        .rejection
        .expect("a pose behind the clock is refused");
    assert_eq!(why.code, tonic::Code::OutOfRange as i32, "{}", why.message);
    assert!(
        why.message.contains("behind the stepped clock"),
        "{}",
        why.message
    );

    let reset_frame = client.reset(pb::ResetRequest {}).await?.into_inner().frame;
    let last_frame = first.iter().map(|s| s.model_frame).max().unwrap_or(0);
    assert!(
        reset_frame > last_frame,
        "reset frame {reset_frame} after frame {last_frame}"
    );
    let second = press_session(&mut client, 0.0).await?;
    assert_eq!(second.len(), first.len());
    for (a, b) in first.iter().zip(&second) {
        assert!(b.rejection.is_none(), "{b:?}");
        assert_eq!(a.force_n, b.force_n, "sample t = {} s", a.t_s);
        assert_eq!(a.contact_count, b.contact_count, "sample t = {} s", a.t_s);
        assert_eq!(a.model_age_s, b.model_age_s, "sample t = {} s", a.t_s);
        assert!(
            b.model_frame >= reset_frame,
            "frame {} before the reset's {reset_frame}",
            b.model_frame
        );
    }
    server.stop().await?;
    Ok(())
}

/// Free-running: frame numbers only increase, across resets with and without
/// a claimed instrument, in the answers, in `Reset`'s reply, in a watcher's
/// stream and in the recording's frame summaries.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_numbers_increase_for_the_life_of_the_server() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("frames.fsrec");
    let options = SimOptions {
        mode: Some(Mode::FreeRunning),
        recording: Some(ToFile::open_at(&path)),
        ..SimOptions::default()
    };
    let server = TestServer::start("cube", options, ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    let watched = tokio::spawn(async move {
        let mut frames = Vec::new();
        while let Ok(Some(f)) = watch.message().await {
            frames.push(f.frame);
        }
        frames
    });
    let mut seen = Vec::new();
    let mut resets = Vec::new();
    for round in 0..3 {
        let mut h = Haptic::open(&mut client, "left", None).await?;
        for i in 0..200 {
            let s = h
                .send(pose(
                    round as f64 + i as f64 * 1e-3,
                    i as u64,
                    press(i),
                    FLAT_DOWN,
                ))
                .await?;
            assert!(s.rejection.is_none(), "{s:?}");
            seen.push(s.model_frame);
            if i == 100 {
                // A reset under the held instrument.
                resets.push(client.reset(pb::ResetRequest {}).await?.into_inner().frame);
            }
            tokio::time::sleep(std::time::Duration::from_millis(1)).await;
        }
        h.close().await;
        // And one with nothing claimed.
        resets.push(client.reset(pb::ResetRequest {}).await?.into_inner().frame);
    }
    assert!(
        seen.windows(2).all(|w| w[0] <= w[1]),
        "answers' frames go back: {seen:?}"
    );
    assert!(
        resets.windows(2).all(|w| w[0] < w[1]),
        "reset frames repeat: {resets:?}"
    );
    let sim = server.sim.clone();
    server.stop().await?;
    let watched = watched.await?;
    assert!(watched.len() > 10, "{} frames watched", watched.len());
    assert!(
        watched.windows(2).all(|w| w[0] < w[1]),
        "watched frames go back or repeat: {watched:?}"
    );
    tokio::task::spawn_blocking(move || sim.recorder().map_or(Ok(()), |r| r.finish())).await??;
    let (entries, truncated) = recording::read(&path)?;
    assert!(!truncated);
    let frames: Vec<u64> = entries
        .iter()
        .filter_map(|e| match &e.entry {
            Some(pb::recording_entry::Entry::Frame(f)) => Some(f.frame),
            _ => None,
        })
        .collect();
    assert!(frames.len() > 10, "{} frames recorded", frames.len());
    assert!(
        frames.windows(2).all(|w| w[0] < w[1]),
        "recorded frames out of order or repeated: {frames:?}"
    );
    for r in &resets {
        assert!(frames.contains(r), "reset frame {r} not recorded");
    }
    Ok(())
}
