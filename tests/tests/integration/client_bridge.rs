//! `fissure bridge` driven from a plain UDP socket against an in-process
//! server on the `cube` scene.

use fissure_cli::client::bridge::{Bridge, FORCE_LEN, decode_force, encode_pose};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use std::time::Duration;
use tokio::net::UdpSocket;

/// Lays the plate flat, face A down (-z), tip towards +y (see cube.toml).
const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Handle height at which face A touches the cube's top (z = 40 mm), m.
const TOUCH_Z: f64 = 0.04 + 0.00075;

fn stepped() -> SimOptions {
    SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    }
}

/// Pose `i` of a press 2 mm into the cube's top over 0.1 s, then a hold.
fn press(i: u64) -> (f64, [f64; 3]) {
    let t = i as f64 * 1e-3;
    let s = (t / 0.1).min(1.0);
    (t, [0.011, 0.005, TOUCH_Z + 0.002 - 0.004 * s])
}

async fn recv(sock: &UdpSocket, buf: &mut [u8]) -> anyhow::Result<usize> {
    Ok(tokio::time::timeout(Duration::from_secs(20), sock.recv(buf)).await??)
}

/// Binary datagrams through the bridge give, sample by sample, exactly the
/// forces a direct gRPC haptic stream gets for the same poses (stepped mode
/// is deterministic); the press is opposed (+z force) and in contact.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn binary_datagrams_match_a_direct_stream() -> anyhow::Result<()> {
    const N: u64 = 200;
    let server = TestServer::start("cube", stepped(), ServeOptions::default()).await?;
    let bridge = Bridge::start(
        &server.url,
        "127.0.0.1:0".parse()?,
        &["left".to_owned()],
        None,
    )
    .await?;
    let device = UdpSocket::bind("127.0.0.1:0").await?;
    device.connect(bridge.local_addr).await?;
    let mut bridged = Vec::new();
    let mut buf = [0u8; 256];
    for i in 1..=N {
        let (t, p) = press(i);
        device.send(&encode_pose(0, i, t, p, FLAT_DOWN)).await?;
        let n = recv(&device, &mut buf).await?;
        assert_eq!(n, FORCE_LEN);
        let f = decode_force(&buf[..n]).expect("a force datagram");
        assert_eq!((f.instrument, f.status, f.sequence), (0, 0, i));
        assert_eq!(f.t_s, t);
        bridged.push(f);
    }
    let stats = bridge.stop().await?;
    assert_eq!(stats.forwarded, N);
    assert_eq!(stats.answered, N);
    assert_eq!(stats.bad, 0);
    server.stop().await?;

    let last = bridged.last().expect("samples");
    assert!(last.contact_count > 0, "no contact at 2 mm depth");
    assert!(
        last.force_n[2] > 0.0,
        "force {:?} does not oppose the push",
        last.force_n
    );

    // The same poses on a direct stream of a fresh server.
    let server = TestServer::start("cube", stepped(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    for (i, b) in (1..=N).zip(&bridged) {
        let (t, p) = press(i);
        let s = haptic.send(pose(t, i, p, FLAT_DOWN)).await?;
        let f = s.force_n.expect("force");
        assert_eq!([f.x, f.y, f.z], b.force_n, "sample {i}");
        assert_eq!(s.contact_count, b.contact_count, "sample {i}");
        assert_eq!(s.model_frame, b.model_frame, "sample {i}");
    }
    haptic.close().await;
    server.stop().await
}

/// JSON datagrams get JSON answers; an unknown instrument is answered
/// `not-forwarded`, a NaN pose `rejected` (the stream stays usable), and a
/// malformed datagram is dropped and counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn json_answers_and_bad_input() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    // Every instrument of the scene: left = 0, right = 1.
    let bridge = Bridge::start(&server.url, "127.0.0.1:0".parse()?, &[], None).await?;
    let device = UdpSocket::bind("127.0.0.1:0").await?;
    device.connect(bridge.local_addr).await?;
    let mut buf = [0u8; 2048];

    let line = |seq: u64, t: f64, z: f64| {
        format!(
            "{{\"instrument\":\"right\",\"seq\":{seq},\"t_s\":{t},\"p\":[0.029,0.005,{z}],\"q\":[0.5,-0.5,0.5,0.5]}}\n"
        )
    };
    device
        .send(line(1, 0.0, TOUCH_Z + 0.001).as_bytes())
        .await?;
    let n = recv(&device, &mut buf).await?;
    let v = std::str::from_utf8(&buf[..n])?;
    assert!(v.starts_with("{\"instrument\":\"right\",\"seq\":1,"), "{v}");
    assert!(v.contains("\"status\":\"ok\""), "{v}");
    assert!(v.contains("\"f\":["), "{v}");
    assert!(v.ends_with("}\n"), "{v}");

    // Garbage: dropped, counted, no answer.
    device.send(b"hello").await?;
    // Unknown instrument index 7 (binary): answered at once, not forwarded.
    device
        .send(&encode_pose(7, 1, 0.0, [0.0; 3], [1.0, 0.0, 0.0, 0.0]))
        .await?;
    let n = recv(&device, &mut buf).await?;
    let f = decode_force(&buf[..n]).expect("a force datagram");
    assert_eq!((f.instrument, f.status), (7, 2));

    // A NaN position for "right" (binary, index 1): rejected by the server
    // with a zero force; the stream stays open.
    device
        .send(&encode_pose(
            1,
            2,
            0.001,
            [0.029, f64::NAN, 0.04],
            [0.5, -0.5, 0.5, 0.5],
        ))
        .await?;
    let n = recv(&device, &mut buf).await?;
    let f = decode_force(&buf[..n]).expect("a force datagram");
    assert_eq!((f.instrument, f.status, f.sequence), (1, 1, 2));
    assert_eq!(f.force_n, [0.0; 3]);

    device
        .send(line(3, 0.002, TOUCH_Z + 0.001).as_bytes())
        .await?;
    let n = recv(&device, &mut buf).await?;
    let v = std::str::from_utf8(&buf[..n])?;
    assert!(v.contains("\"seq\":3,"), "{v}");
    assert!(v.contains("\"status\":\"ok\""), "{v}");

    let stats = bridge.stop().await?;
    assert_eq!(stats.bad, 1);
    assert_eq!(stats.not_forwarded, 1);
    assert_eq!(stats.rejected, 1);
    assert_eq!(stats.answered, 4);
    // After the bridge stopped, its claims are released.
    let mut client = server.client().await?;
    let h = Haptic::open(&mut client, "right", None).await?;
    h.close().await;
    server.stop().await
}
