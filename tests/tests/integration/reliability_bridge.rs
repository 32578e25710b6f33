//! `fissure bridge` under malformed datagrams: each kind is dropped and
//! counted without an answer, and the bridge keeps serving the device.

use fissure_cli::client::bridge::{
    Bridge, FORCE_LEN, FORCE_MAGIC, ForceDatagram, MAX_DATAGRAM, decode_force, encode_force,
    encode_pose,
};
use fissure_engine::sim::SimOptions;
use fissure_server::ServeOptions;
use fissure_tests::TestServer;
use std::time::Duration;
use tokio::net::UdpSocket;

use crate::reliability_common::{FLAT_DOWN, HANDLE_Y, LEFT_X, TOUCH_Z};

/// A pose of `left` 1 mm above the cube (no contact).
fn above(seq: u64) -> [u8; 80] {
    encode_pose(
        0,
        seq,
        seq as f64 * 1e-3,
        [LEFT_X, HANDLE_Y, TOUCH_Z + 0.001],
        FLAT_DOWN,
    )
}

async fn answer(device: &UdpSocket) -> anyhow::Result<ForceDatagram> {
    let mut buf = [0u8; 256];
    let n = tokio::time::timeout(Duration::from_secs(20), device.recv(&mut buf)).await??;
    decode_force(&buf[..n]).ok_or_else(|| anyhow::anyhow!("not a force datagram: {n} bytes"))
}

/// Truncated, over-long, wrong magic or version, a force datagram looped
/// back, JSON with NaN, with a missing field, cut short, a datagram of the
/// largest UDP size: each is dropped and counted, none is answered, and the
/// valid poses around them are served in order.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_datagrams_are_dropped_and_the_bridge_keeps_serving() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let bridge = Bridge::start(
        &server.url,
        "127.0.0.1:0".parse()?,
        &["left".to_owned()],
        None,
    )
    .await?;
    let device = UdpSocket::bind("127.0.0.1:0").await?;
    device.connect(bridge.local_addr).await?;

    let good = above(1);
    let mut version = above(2);
    version[4] = 2;
    let mut force = [0u8; FORCE_LEN];
    encode_force(&ForceDatagram::empty(0, 0, 2, 0.002), &mut force);
    assert_eq!(force[..4], FORCE_MAGIC);
    let mut long = above(2).to_vec();
    long.resize(MAX_DATAGRAM + 1, 0);
    let json = br#"{"instrument":"left","seq":2,"t_s":0.002,"p":[0.011,0.005,0.042],"q":[0.5,-0.5,0.5,0.5]}"#;
    let bad: Vec<(&str, Vec<u8>)> = vec![
        ("truncated", good[..79].to_vec()),
        ("one byte long", [&good[..], &[0]].concat()),
        ("magic only", good[..4].to_vec()),
        ("version 2", version.to_vec()),
        ("a force datagram looped back", force.to_vec()),
        ("over MAX_DATAGRAM", long),
        ("largest UDP payload", vec![b'{'; 65_507]),
        ("blank", b" \n".to_vec()),
        (
            "JSON NaN",
            br#"{"i":0,"seq":2,"t_s":NaN,"p":[0,0,0],"q":[1,0,0,0]}"#.to_vec(),
        ),
        (
            "JSON missing seq",
            br#"{"i":0,"t_s":0.002,"p":[0,0,0],"q":[1,0,0,0]}"#.to_vec(),
        ),
        ("JSON cut short", json[..json.len() - 1].to_vec()),
    ];

    device.send(&good).await?;
    let f = answer(&device).await?;
    assert_eq!((f.status, f.sequence), (0, 1));
    for (what, bytes) in &bad {
        let sent = device.send(bytes).await?;
        assert_eq!(sent, bytes.len(), "{what}");
    }
    // The next valid pose is the next answer: nothing above was answered.
    device.send(&above(3)).await?;
    let f = answer(&device).await?;
    assert_eq!((f.status, f.sequence), (0, 3));
    device.send(json).await?;
    let mut buf = [0u8; 1024];
    let n = tokio::time::timeout(Duration::from_secs(20), device.recv(&mut buf)).await??;
    let line = std::str::from_utf8(&buf[..n])?;
    // seq 2 after 3: the server rejects it (time going back), the bridge
    // relays that.
    assert!(line.contains("\"status\":\"rejected\""), "{line}");

    let stats = bridge.stop().await?;
    assert_eq!(stats.bad, bad.len() as u64, "{stats:?}");
    assert_eq!(stats.received, bad.len() as u64 + 3);
    assert_eq!((stats.forwarded, stats.answered), (3, 3));
    assert_eq!(stats.rejected, 1);
    server.stop().await?;
    Ok(())
}
