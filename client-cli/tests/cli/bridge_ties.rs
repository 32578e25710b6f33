//! Ties cut or torn in a session reach the bridges' peers: OpenIGTLink as a
//! STATUS per tie (device `fissure_ties`), UDP with `--tie-events` as a
//! datagram per tie (`b"FST1"`). The scene: `sylvian` on the coarse phantom
//! with weak trabeculae (rupture strain 0.2), its left spatula inserted
//! 20 mm and lifted 5 mm in stepped mode over 400 poses (20 deformation
//! steps); the weak ties tear as the wall lifts. The law: each tie the
//! frames report torn comes once, as torn, and none twice.
//!
//! The same session's assessment alerts (the scene's `[assessment]` with
//! a low pressure level, 50 Pa to warn and 500 Pa to fail, that the lift
//! passes): the mean retraction pressure under the spatula is announced
//! once at each level, warn before fail, with its value at or above the
//! level (OpenIGTLink: STATUS `ASSESS_WARN` and `ASSESS_FAIL`, device
//! `fissure_assess`; UDP with `--assess-events`: `b"FSA1"` datagrams).

use fissure_cli::client::bridge::igtl::codec::{
    self, Body, HEADER_LEN, Transform, name_field, parse_message, s_to_timestamp,
    transform_content, type_field, write_message,
};
use fissure_cli::client::bridge::igtl::{IgtlBridge, IgtlOptions};
use fissure_cli::client::bridge::{
    ALERT_LEN, Bridge, FORCE_LEN, TIE_LEN, UdpOptions, decode_alert, decode_force, decode_tie,
    encode_pose,
};
use fissure_engine::scene::Scene;
use fissure_engine::sim::core::stepped::home_pose;
use fissure_engine::sim::{Mode, SimOptions, Simulation};
use fissure_server::{RunningServer, ServeOptions, serve};
use nalgebra::{Isometry3, Translation3, Vector3};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpStream, UdpSocket};

/// Poses of the session.
const POSES: u64 = 400;

struct Server {
    url: String,
    server: RunningServer,
    sim: Arc<Simulation>,
    home: Isometry3<f64>,
}

/// An in-process stepped server on the weak-ties scene.
async fn start_server() -> anyhow::Result<Server> {
    let text = include_str!("../../../server/scenes/sylvian.toml").replace("paper-48k", "coarse");
    let cut = text.rfind("[[instrument]]").expect("two instruments");
    let text = format!(
        "{}\n[[ties]]\nkind = \"trabecula\"\nregion = {{ landmark = \"sylvian-left\" }}\ndensity_per_mm2 = 0.2\nseed = 11\nstiffness_n_per_m = 0.5\nmax_gap_m = 0.010\nrupture_strain = 0.2\n\n[assessment]\npressure_pa = {{ warn = 50.0, fail = 500.0 }}\n",
        &text[..cut]
    );
    let scene = Scene::parse(&text, "test")?;
    let home = home_pose(&scene, 0);
    let options = SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    };
    let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
    let server = serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
    server.set_simulation(sim.clone()).await;
    Ok(Server {
        url: format!("http://{}", server.addr),
        server,
        sim,
        home,
    })
}

impl Server {
    /// Pose `i` (1-based) of the session: inserted over the first half,
    /// lifted over the second.
    fn pose(&self, i: u64) -> Isometry3<f64> {
        let k = i as f64 / POSES as f64;
        Translation3::from(Vector3::new(
            0.020 * (2.0 * k).min(1.0),
            0.0,
            0.005 * (2.0 * k - 1.0).max(0.0),
        )) * self.home
    }

    async fn stop(self) -> anyhow::Result<()> {
        self.server.shutdown().await?;
        let sim = self.sim.clone();
        tokio::task::spawn_blocking(move || sim.shutdown()).await?;
        Ok(())
    }
}

async fn read_one(s: &mut TcpStream) -> anyhow::Result<(codec::Header, Body)> {
    let mut head = [0u8; HEADER_LEN];
    tokio::time::timeout(Duration::from_secs(20), s.read_exact(&mut head)).await??;
    let h = codec::parse_header(&head)?;
    let mut body = vec![0u8; h.body_size as usize];
    s.read_exact(&mut body).await?;
    let mut whole = head.to_vec();
    whole.extend_from_slice(&body);
    Ok(parse_message(&whole)?)
}

/// Each tie once.
fn once(torn: &[u32]) {
    assert!(!torn.is_empty(), "no tie tore");
    let mut o = torn.to_vec();
    o.sort_unstable();
    o.dedup();
    assert_eq!(o.len(), torn.len(), "a tie announced twice: {torn:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn torn_ties_reach_an_igtl_peer_as_status_messages() -> anyhow::Result<()> {
    let server = start_server().await?;
    let options = IgtlOptions {
        listen: Some("127.0.0.1:0".parse()?),
        surface_device: None,
        ..IgtlOptions::default()
    };
    let bridge = IgtlBridge::start(&server.url, &["left".to_owned()], None, &options).await?;
    let mut s = TcpStream::connect(bridge.local_addr.expect("listening")).await?;
    let mut torn = Vec::new();
    let mut alerts = Vec::new();
    for i in 1..=POSES {
        let pose = server.pose(i);
        let r = pose.rotation.to_rotation_matrix();
        let t = Transform {
            rotation: std::array::from_fn(|a| std::array::from_fn(|b| r[(a, b)] as f32)),
            // Millimetres (the bridge's default unit).
            translation: (pose.translation.vector * 1000.0).map(|x| x as f32).into(),
        };
        let mut msg = Vec::new();
        write_message(
            &mut msg,
            type_field("TRANSFORM"),
            name_field("left").expect("a device name"),
            s_to_timestamp(i as f64 * 1e-3),
            |o| transform_content(&t, o),
        );
        s.write_all(&msg).await?;
        // Up to this pose's torque SENSOR (tie STATUS messages may come
        // before it).
        loop {
            let (h, body) = read_one(&mut s).await?;
            match body {
                Body::Status(st) if h.device() == "fissure_ties" => {
                    assert_eq!(st.error_name, "TIE_TORN", "{st:?}");
                    assert!(st.message.starts_with("trabecula "), "{st:?}");
                    torn.push(u32::try_from(st.subcode)?);
                }
                Body::Status(st)
                    if h.device() == "fissure_assess"
                        && st.message.contains("mean retraction pressure") =>
                {
                    alerts.push((st.error_name.clone(), st.subcode));
                }
                Body::Sensor(_) if h.device() == "left_torque" => break,
                _ => {}
            }
        }
    }
    once(&torn);
    assert_eq!(
        alerts,
        [("ASSESS_WARN".to_owned(), 1), ("ASSESS_FAIL".to_owned(), 2)],
        "the pressure's alerts"
    );
    drop(s);
    bridge.stop().await?;
    server.stop().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn torn_ties_reach_a_udp_device_as_tie_datagrams() -> anyhow::Result<()> {
    let server = start_server().await?;
    let bridge = Bridge::start_with(
        &server.url,
        "127.0.0.1:0".parse()?,
        &[],
        None,
        UdpOptions {
            tie_events: true,
            assess_events: true,
        },
    )
    .await?;
    let device = UdpSocket::bind("127.0.0.1:0").await?;
    device.connect(bridge.local_addr).await?;
    let mut torn = Vec::new();
    let mut alerts = Vec::new();
    let mut alert_count = 0u64;
    let mut buf = [0u8; 2048];
    for i in 1..=POSES {
        let pose = server.pose(i);
        let q = pose.rotation.quaternion();
        let p = pose.translation.vector;
        let d = encode_pose(0, i, i as f64 * 1e-3, [p.x, p.y, p.z], [q.w, q.i, q.j, q.k]);
        device.send(&d).await?;
        // Up to this pose's force answer (tie datagrams may come before).
        loop {
            let n = tokio::time::timeout(Duration::from_secs(20), device.recv(&mut buf)).await??;
            if n == TIE_LEN {
                let t = decode_tie(&buf[..n]).expect("a tie datagram");
                assert_eq!((t.instrument, t.kind, t.cause), (0, 1, 2), "{t:?}");
                assert!(t.strain >= 0.2 && t.t_s > 0.0, "{t:?}");
                torn.push(t.tie);
            } else if n == ALERT_LEN {
                let a = decode_alert(&buf[..n]).expect("an alert datagram");
                alert_count += 1;
                assert!(a.value >= a.level && a.t_s > 0.0, "{a:?}");
                if a.measure == 1 {
                    assert_eq!(a.instrument, 0, "{a:?}");
                    alerts.push(a.grade);
                }
            } else if n == FORCE_LEN {
                let f = decode_force(&buf[..n]).expect("a force datagram");
                if f.sequence == i {
                    break;
                }
            }
        }
    }
    once(&torn);
    assert_eq!(alerts, [1, 2], "the pressure's alerts: warn, then fail");
    let stats = bridge.stop().await?;
    assert_eq!(stats.tie_events, torn.len() as u64);
    assert_eq!(stats.assess_events, alert_count);
    server.stop().await
}
