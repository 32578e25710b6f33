//! `fissure bench bridge`: the latency the device bridges add to a force
//! round trip. One in-process server (free-running) per bridge path on the
//! `cube` scene; two clients hold the spatulas pressed 1 mm into the cube's
//! top, one pose per tick of `--rate-hz` each, each waiting for its answer
//! (lockstep, as a haptic servo loop does):
//!
//! * `left` on a haptic stream straight to the server (the reference,
//!   `grpc_*`);
//! * `right` through the bridge of the path: `udp` (binary datagrams through
//!   `fissure bridge`), `igtl` (TRANSFORM messages through `fissure bridge
//!   --igtl-listen`, answered by the two SENSOR messages, no surface) or
//!   `igtl+surface` (the same with the deformed surface streamed as POLYDATA
//!   on the same connection at the deformation rate).
//!
//! The two round trips of a tick run one after the other, in alternating
//! order, so that both see the same machine (a shared machine's noise
//! otherwise dominates a 99th percentile). A round trip runs from just
//! before the send to the answer's arrival (for OpenIGTLink, the torque
//! SENSOR, the second of the pair). The clients run on a thread and runtime
//! of their own, paced by `std::thread::sleep` (tokio's timer has
//! millisecond resolution). `added_*` is the bridge's percentile less the
//! direct stream's of the same run.

use crate::client::bridge::igtl::codec::{
    self, HEADER_LEN, Transform, name_field, transform_content, type_field, write_message,
};
use crate::client::bridge::igtl::{IgtlBridge, IgtlOptions};
use crate::client::bridge::{Bridge, FORCE_LEN, decode_force, encode_pose};
use crate::client::replay::{connect, haptic_request};
use anyhow::Context;
use fissure_engine::scene::Scene;
use fissure_engine::sim::runtime::stats::percentile;
use fissure_engine::sim::{Mode, SimOptions, Simulation};
use fissure_proto::v1 as pb;
use fissure_server::{ServeOptions, serve};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Options of `fissure bench bridge`.
#[derive(Debug, Clone, clap::Args)]
pub struct BridgeBenchArgs {
    /// Timed samples per path.
    #[arg(long, default_value_t = 5000)]
    pub samples: usize,
    /// Pose rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    pub rate_hz: f64,
    /// Samples sent before the timed ones (connections and caches warm).
    #[arg(long, default_value_t = 500)]
    pub warmup: usize,
    /// Bridge paths to time (udp, igtl, igtl+surface); all by default.
    #[arg(long, value_delimiter = ',')]
    pub path: Vec<String>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One path's round trips, us.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PathRow {
    /// `udp`, `igtl` or `igtl+surface`.
    pub path: String,
    /// Timed samples answered on each client.
    pub samples: usize,
    /// The direct stream's median round trip in the same run, us.
    pub grpc_p50_us: f64,
    /// The direct stream's 99th percentile, us.
    pub grpc_p99_us: f64,
    /// The bridged median round trip, us.
    pub p50_us: f64,
    /// The bridged 99th percentile, us.
    pub p99_us: f64,
    /// The bridged largest, us.
    pub max_us: f64,
    /// `p50_us - grpc_p50_us`.
    pub added_p50_us: f64,
    /// `p99_us - grpc_p99_us`.
    pub added_p99_us: f64,
    /// Bridged samples whose round trip was longer than a tick.
    pub over_period: usize,
    /// POLYDATA messages read between the answers (`igtl+surface`).
    pub polydata: usize,
}

/// What `fissure bench bridge` measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BridgeBenchReport {
    /// Scene.
    pub scene: String,
    /// Pose rate, Hz.
    pub rate_hz: f64,
    /// One row per path.
    pub rows: Vec<PathRow>,
}

/// The held poses: the plates flat, face A 1 mm into the cube's top.
const LEFT_M: [f64; 3] = [0.011, 0.005, 0.04075 - 0.001];
const RIGHT_M: [f64; 3] = [0.029, 0.005, 0.04075 - 0.001];
const ORIENTATION: [f64; 4] = [0.5, -0.5, 0.5, 0.5];

/// A path's client: sends pose `i` and waits for its answer.
enum Client {
    Grpc {
        tx: tokio::sync::mpsc::Sender<pb::PoseSample>,
        rx: tonic::Streaming<pb::ForceSample>,
        _client: fissure_proto::v1::fissure_client::FissureClient<tonic::transport::Channel>,
    },
    Udp(tokio::net::UdpSocket),
    Igtl {
        stream: tokio::net::TcpStream,
        message: Vec<u8>,
        body: Vec<u8>,
        polydata: usize,
    },
}

impl Client {
    async fn round_trip(&mut self, i: u64) -> anyhow::Result<()> {
        let t_s = i as f64 * 1e-3;
        match self {
            Client::Grpc { tx, rx, .. } => {
                tx.send(pb::PoseSample::new(t_s, i, LEFT_M, ORIENTATION))
                    .await
                    .context("the haptic stream closed")?;
                rx.message().await?.context("the haptic stream ended")?;
            }
            Client::Udp(sock) => {
                sock.send(&encode_pose(0, i, t_s, RIGHT_M, ORIENTATION))
                    .await?;
                let mut buf = [0u8; 256];
                let n = sock.recv(&mut buf).await?;
                anyhow::ensure!(n == FORCE_LEN, "an answer of {n} bytes");
                let f = decode_force(&buf[..n]).context("a force datagram")?;
                anyhow::ensure!(f.sequence == i, "answer {} to pose {i}", f.sequence);
            }
            Client::Igtl {
                stream,
                message,
                body,
                polydata,
            } => {
                let [qw, qx, qy, qz] = ORIENTATION;
                let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                    qw, qx, qy, qz,
                ));
                let r = q.to_rotation_matrix();
                let t = Transform {
                    rotation: std::array::from_fn(|a| std::array::from_fn(|b| r[(a, b)] as f32)),
                    translation: RIGHT_M.map(|x| (x * 1000.0) as f32),
                };
                write_message(
                    message,
                    type_field("TRANSFORM"),
                    name_field("right").unwrap_or([0; 20]),
                    codec::s_to_timestamp(1.0 + t_s),
                    |o| transform_content(&t, o),
                );
                stream.write_all(message).await?;
                let mut head = [0u8; HEADER_LEN];
                loop {
                    stream.read_exact(&mut head).await?;
                    let h = codec::parse_header(&head)?;
                    body.resize(h.body_size as usize, 0);
                    stream.read_exact(body).await?;
                    match (h.type_str(), h.device()) {
                        ("SENSOR", "right_torque") => break,
                        ("POLYDATA", _) => *polydata += 1,
                        _ => {}
                    }
                }
            }
        }
        Ok(())
    }
}

async fn open_client(
    path: &str,
    url: &str,
    bridge_addr: Option<std::net::SocketAddr>,
) -> anyhow::Result<Client> {
    Ok(match path {
        "grpc" => {
            let mut client = connect(url).await?;
            let (tx, rx) = tokio::sync::mpsc::channel(16);
            let req = haptic_request(
                tokio_stream::wrappers::ReceiverStream::new(rx),
                "left",
                None,
            )?;
            let rx = client.haptic(req).await?.into_inner();
            Client::Grpc {
                tx,
                rx,
                _client: client,
            }
        }
        "udp" => {
            let s = tokio::net::UdpSocket::bind("127.0.0.1:0").await?;
            s.connect(bridge_addr.context("a bridge")?).await?;
            Client::Udp(s)
        }
        _ => {
            let stream = tokio::net::TcpStream::connect(bridge_addr.context("a bridge")?).await?;
            stream.set_nodelay(true)?;
            Client::Igtl {
                stream,
                message: Vec::with_capacity(128),
                body: Vec::with_capacity(1 << 16),
                polydata: 0,
            }
        }
    })
}

/// Drives the direct client and the bridged one (`path`) on a thread of
/// their own; returns the timed round trips of each, us, and the POLYDATA
/// messages read.
fn drive(
    path: String,
    url: String,
    bridge_addr: Option<std::net::SocketAddr>,
    args: BridgeBenchArgs,
) -> anyhow::Result<(Vec<f64>, Vec<f64>, usize)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let mut direct = open_client("grpc", &url, None).await?;
        let mut bridged = open_client(&path, &url, bridge_addr).await?;
        let period = Duration::from_secs_f64(1.0 / args.rate_hz);
        let total = args.warmup + args.samples;
        let (mut grpc, mut via) = (
            Vec::with_capacity(args.samples),
            Vec::with_capacity(args.samples),
        );
        let mut next = Instant::now();
        for i in 0..total {
            let now = Instant::now();
            if next > now {
                // Blocking on purpose: this runtime has nothing else to run
                // between samples, and tokio's timer is too coarse.
                std::thread::sleep(next - now);
            }
            next += period;
            let seq = i as u64 + 1;
            let mut times = [0.0; 2];
            for k in 0..2 {
                // Alternate which client goes first.
                let bridge_turn = (k + i) % 2 == 1;
                let t0 = Instant::now();
                if bridge_turn {
                    bridged.round_trip(seq).await?;
                } else {
                    direct.round_trip(seq).await?;
                }
                times[usize::from(bridge_turn)] = t0.elapsed().as_secs_f64() * 1e6;
            }
            if i >= args.warmup {
                grpc.push(times[0]);
                via.push(times[1]);
            }
        }
        let polydata = match bridged {
            Client::Igtl { polydata, .. } => polydata,
            _ => 0,
        };
        anyhow::Ok((grpc, via, polydata))
    })
}

/// Times every path.
pub async fn run(args: &BridgeBenchArgs) -> anyhow::Result<BridgeBenchReport> {
    const PATHS: [&str; 3] = ["udp", "igtl", "igtl+surface"];
    let paths: Vec<String> = if args.path.is_empty() {
        PATHS.map(String::from).to_vec()
    } else {
        args.path.clone()
    };
    for p in &paths {
        anyhow::ensure!(
            PATHS.contains(&p.as_str()),
            "--path {p}: one of udp, igtl, igtl+surface"
        );
    }
    let scene_name = "cube";
    let mut rows = Vec::new();
    for path in &paths {
        let (scene, _) = Scene::load(scene_name)?;
        let options = SimOptions {
            mode: Some(Mode::FreeRunning),
            ..SimOptions::default()
        };
        let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
        let server = serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
        server.set_simulation(sim.clone()).await;
        let url = format!("http://{}", server.addr);
        let right = ["right".to_owned()];
        let (udp, igtl) = if path == "udp" {
            (
                Some(Bridge::start(&url, "127.0.0.1:0".parse()?, &right, None).await?),
                None,
            )
        } else {
            let options = IgtlOptions {
                listen: Some("127.0.0.1:0".parse()?),
                surface_device: (path == "igtl+surface").then(|| "fissure_surface".into()),
                ..IgtlOptions::default()
            };
            (
                None,
                Some(IgtlBridge::start(&url, &right, None, &options).await?),
            )
        };
        let addr = udp
            .as_ref()
            .map(|b| b.local_addr)
            .or_else(|| igtl.as_ref().and_then(|b| b.local_addr));
        let (p, u, a) = (path.clone(), url.clone(), args.clone());
        let result = tokio::task::spawn_blocking(move || drive(p, u, addr, a)).await?;
        if let Some(b) = udp {
            b.stop().await?;
        }
        if let Some(b) = igtl {
            b.stop().await?;
        }
        server.shutdown().await?;
        tokio::task::spawn_blocking(move || sim.shutdown()).await?;
        let (mut grpc, mut via, polydata) = result.with_context(|| format!("path {path}"))?;
        grpc.sort_by(f64::total_cmp);
        via.sort_by(f64::total_cmp);
        let period_us = 1e6 / args.rate_hz;
        let (g50, g99) = (percentile(&grpc, 0.5), percentile(&grpc, 0.99));
        let (p50, p99) = (percentile(&via, 0.5), percentile(&via, 0.99));
        rows.push(PathRow {
            path: path.clone(),
            samples: via.len(),
            grpc_p50_us: g50,
            grpc_p99_us: g99,
            p50_us: p50,
            p99_us: p99,
            max_us: via.last().copied().unwrap_or(f64::NAN),
            added_p50_us: p50 - g50,
            added_p99_us: p99 - g99,
            over_period: via.iter().filter(|&&r| r > period_us).count(),
            polydata,
        });
    }
    Ok(BridgeBenchReport {
        scene: scene_name.to_owned(),
        rate_hz: args.rate_hz,
        rows,
    })
}

/// The report as a table.
pub fn table(r: &BridgeBenchReport) -> String {
    let mut s = format!(
        "bridge round trips, scene {}, {} Hz lockstep, us (grpc: the direct stream of the same run; added = bridged - grpc)\n",
        r.scene, r.rate_hz
    );
    s += &format!(
        "{:<14} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10} {:>10} {:>7} {:>9}\n",
        "path",
        "samples",
        "grpc p50",
        "grpc p99",
        "p50",
        "p99",
        "max",
        "added p50",
        "added p99",
        "> tick",
        "polydata"
    );
    for x in &r.rows {
        s += &format!(
            "{:<14} {:>8} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>10.1} {:>10.1} {:>7} {:>9}\n",
            x.path,
            x.samples,
            x.grpc_p50_us,
            x.grpc_p99_us,
            x.p50_us,
            x.p99_us,
            x.max_us,
            x.added_p50_us,
            x.added_p99_us,
            x.over_period,
            x.polydata
        );
    }
    s
}

/// Runs `fissure bench bridge` and prints the table or JSON.
pub async fn main(args: &BridgeBenchArgs) -> anyhow::Result<()> {
    let r = run(args).await?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        print!("{}", table(&r));
    }
    Ok(())
}
