//! `fissure bridge`: a UDP bridge for haptic device programs that do not
//! speak gRPC. It holds one haptic stream per instrument to the server,
//! forwards each pose datagram it receives to the instrument's stream and
//! sends the force sample that answers it back to the datagram's sender, in
//! the sender's format (binary or JSON). With `--igtl-listen` or
//! `--igtl-connect` it speaks OpenIGTLink over TCP instead, for 3D Slicer
//! and PLUS ([`igtl`]: TRANSFORM and POSITION in; SENSOR, STATUS and the
//! deformed surface as POLYDATA out).
//!
//! # Datagram format
//!
//! One pose per datagram. All numbers little-endian; f64 is IEEE 754
//! binary64. Units: s, m, N, N m.
//!
//! **Binary pose** (device -> bridge), [`POSE_LEN`] = 80 bytes:
//!
//! | offset | type      | field                                                  |
//! |-------:|-----------|--------------------------------------------------------|
//! | 0      | [u8; 4]   | magic `b"FSP1"`                                        |
//! | 4      | u8        | version = 1                                            |
//! | 5      | u8        | instrument index (order of `--instrument`, or the scene's) |
//! | 6      | u16       | reserved, 0                                            |
//! | 8      | u64       | sequence, strictly increasing per instrument           |
//! | 16     | f64       | t_s, s, non-decreasing per instrument                  |
//! | 24     | 3 x f64   | position of the handle point x, y, z, m (scene frame)  |
//! | 48     | 4 x f64   | orientation quaternion w, x, y, z (unit within 1e-3)   |
//!
//! **Binary force** (bridge -> device), [`FORCE_LEN`] = 112 bytes:
//!
//! | offset | type      | field                                                  |
//! |-------:|-----------|--------------------------------------------------------|
//! | 0      | [u8; 4]   | magic `b"FSF1"`                                        |
//! | 4      | u8        | version = 1                                            |
//! | 5      | u8        | instrument index                                       |
//! | 6      | u16       | status: 0 ok, 1 pose rejected by the server, 2 not forwarded (unknown instrument, stream down or full) |
//! | 8      | u64       | sequence of the pose answered                          |
//! | 16     | f64       | t_s of the pose answered, s                            |
//! | 24     | 3 x f64   | force on the instrument, N (scene frame)               |
//! | 48     | 3 x f64   | torque about the handle point, N m                     |
//! | 72     | u32       | contact count (surface vertices)                       |
//! | 76     | u32       | safety flags (`fissure.v1.SafetyFlag` bits)            |
//! | 80     | u64       | model frame (deformation step used)                    |
//! | 88     | f64       | model age, s                                           |
//! | 96     | f64       | server compute time, us                                |
//! | 104    | u64       | reserved, 0                                            |
//!
//! **Binary tie event** (bridge -> device, with `--tie-events`, in scenes
//! with ties), [`TIE_LEN`] = 64 bytes, sent to every device that has sent a
//! pose (binary ones), once per tie cut or torn:
//!
//! | offset | type      | field                                                  |
//! |-------:|-----------|--------------------------------------------------------|
//! | 0      | [u8; 4]   | magic `b"FST1"`                                        |
//! | 4      | u8        | version = 1                                            |
//! | 5      | u8        | instrument index that cut it, or (torn) the pushing one whose tip was nearest; 255: not bridged |
//! | 6      | u8        | kind: 1 arachnoid trabecula, 2 bridging vessel, 0 not known |
//! | 7      | u8        | cause: 1 cut, 2 torn, 0 released in a frame the bridge did not receive (then time, place and strain are NaN) |
//! | 8      | u32       | the tie's index in the scene                           |
//! | 12     | u32       | reserved, 0                                            |
//! | 16     | f64       | simulation time of the step, s                         |
//! | 24     | 3 x f64   | the tie's midpoint when it went, m (scene frame)       |
//! | 48     | f64       | its strain (L - L0) / L0 when it went                  |
//! | 56     | u64       | reserved, 0                                            |
//!
//! A torn vessel (kind 2, cause 2) is an injury; the force samples of the
//! instrument that tore it also carry `SAFETY_FLAG_VESSEL_TORN`.
//!
//! **Binary assessment alert** (`fissure bridge --assess-events`),
//! [`ALERT_LEN`] = 32 bytes, sent to every device that has sent a pose
//! (binary ones) when a measure of the assessment (`fissure report`: the
//! retraction pressure, the tissue's strain) first reaches its warning
//! level and its failing level, so that a device program can warn the
//! trainee during the session:
//!
//! | offset | type      | field                                                  |
//! |-------:|-----------|--------------------------------------------------------|
//! | 0      | [u8; 4]   | magic `b"FSA1"`                                        |
//! | 4      | u8        | version = 1                                            |
//! | 5      | u8        | level reached: 1 warn, 2 fail                          |
//! | 6      | u8        | measure: 1 mean retraction pressure (Pa), 2 time above the warning pressure (s), 3 pressure-time product (Pa s), 4 principal strain, 5 tissue volume above the warning strain (m^3) |
//! | 7      | u8        | instrument index; 255: the tissue's measure            |
//! | 8      | f64       | simulation time of the step, s                         |
//! | 16     | f64       | the value (SI)                                         |
//! | 24     | f64       | the level it reached (SI)                              |
//!
//! **JSON** (one object per datagram, a trailing newline allowed): a
//! datagram whose first non-blank byte is `{` is read as
//! `{"instrument": "left", "seq": 7, "t_s": 0.007, "p": [x, y, z],
//! "q": [w, x, y, z]}` (`"instrument"` may instead be `"i": 0`, the index).
//! The answer is one line:
//! `{"instrument":"left","seq":7,"t_s":0.007,"status":"ok","f":[..],"torque":[..],"contacts":3,"flags":0,"model_frame":12,"model_age_s":0.004,"server_us":41.0}`
//! with `"status"` `"ok"`, `"rejected"` (then `"message"` says why) or
//! `"not-forwarded"`. A tie event to a JSON device is one line:
//! `{"event":"tie","tie":4,"cause":"cut","kind":"trabecula","instrument":"blade","t_s":1.25,"p":[..],"strain":0.125}`
//! (`"cause"` `"cut"`, `"torn"` or `"released"`, the last with no more
//! fields). An assessment alert to a JSON device is one line:
//! `{"event":"assessment","grade":"warn","measure":"mean retraction pressure","instrument":"left","t_s":1.25,"value":2.7e3,"level":2.666e3,"unit":"Pa"}`.
//!
//! Datagrams that do not parse, and any over [`MAX_DATAGRAM`] bytes, are
//! dropped and counted ([`parse_datagram`] names what is wrong; it never
//! panics). The parser is fuzzed (`server/fuzz`, target `bridge`).
//!
//! # Rate and allocation
//!
//! The bridge is sized for 1 kHz per instrument: the receive buffer, the
//! reply buffers and the queues of pending replies are allocated once; a
//! sample costs no allocation in the bridge (the gRPC transport below it
//! manages its own buffers). A pose arriving while the instrument's stream
//! has [`QUEUE`] poses in flight is answered `not forwarded` at once rather
//! than queued, so a stalled server never delays the device's loop.
//!
//! # Layout
//!
//! [`codec`] reads and writes the datagrams; [`lanes`] holds the haptic
//! streams and the answers owed, for this protocol and any other; this module
//! is the UDP loop; [`igtl`] is the OpenIGTLink bridge on the same lanes.

pub mod codec;
pub mod igtl;
pub mod lanes;
pub mod ties;

pub use codec::*;
pub use lanes::{Answers, Lanes, QUEUE};

use crate::client::replay::connect;
use anyhow::{Context, bail};
use fissure_proto::v1 as pb;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::net::UdpSocket;

/// Counters of a bridge.
#[derive(Debug, Default)]
pub struct Counters {
    /// Datagrams received.
    pub received: AtomicU64,
    /// Datagrams that did not parse.
    pub bad: AtomicU64,
    /// Poses forwarded to the server.
    pub forwarded: AtomicU64,
    /// Poses answered `not forwarded`.
    pub not_forwarded: AtomicU64,
    /// Force answers sent back.
    pub answered: AtomicU64,
    /// Poses the server rejected.
    pub rejected: AtomicU64,
    /// Tie datagrams sent (one per tie and device).
    pub tie_events: AtomicU64,
    /// Assessment alert datagrams sent (one per alert and device).
    pub assess_events: AtomicU64,
}

/// A snapshot of [`Counters`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct BridgeStats {
    /// Datagrams received.
    pub received: u64,
    /// Datagrams that did not parse.
    pub bad: u64,
    /// Poses forwarded to the server.
    pub forwarded: u64,
    /// Poses answered `not forwarded`.
    pub not_forwarded: u64,
    /// Force answers sent back.
    pub answered: u64,
    /// Poses the server rejected.
    pub rejected: u64,
    /// Tie datagrams sent (one per tie and device).
    pub tie_events: u64,
    /// Assessment alert datagrams sent (one per alert and device).
    pub assess_events: u64,
}

impl Counters {
    fn snapshot(&self) -> BridgeStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        BridgeStats {
            received: l(&self.received),
            bad: l(&self.bad),
            forwarded: l(&self.forwarded),
            not_forwarded: l(&self.not_forwarded),
            answered: l(&self.answered),
            rejected: l(&self.rejected),
            tie_events: l(&self.tie_events),
            assess_events: l(&self.assess_events),
        }
    }
}

/// Where the answer of a pose in flight goes.
#[derive(Debug, Clone, Copy)]
struct Pending {
    to: SocketAddr,
    format: Format,
}

/// A running bridge.
pub struct Bridge {
    /// The UDP address it listens on.
    pub local_addr: SocketAddr,
    /// Its counters.
    pub counters: Arc<Counters>,
    stop: tokio::sync::watch::Sender<bool>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
}

/// Options of `fissure bridge`.
#[derive(Debug, Clone, clap::Args)]
pub struct BridgeArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    pub server: String,
    /// UDP address to listen on for pose datagrams.
    #[arg(long, default_value = "127.0.0.1:50052")]
    pub listen: SocketAddr,
    /// Instrument(s) to claim, in index order (repeatable); default: every
    /// instrument of the scene, in the scene's order.
    #[arg(long)]
    pub instrument: Vec<String>,
    /// Bearer token for the claims (also FISSURE_TOKEN).
    #[arg(long, env = "FISSURE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Stop after this long, s (default: until Ctrl-C).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// UDP: send every device that has sent a pose a datagram per tie
    /// (arachnoid trabecula, bridging vessel) cut or torn, in the device's
    /// format (binary b"FST1" or a JSON line; module documentation).
    #[arg(long)]
    pub tie_events: bool,
    /// UDP: send every device that has sent a pose a datagram when a
    /// measure of the assessment (retraction pressure, tissue strain) first
    /// reaches its warning and its failing level (the scene's
    /// `[assessment]`), in the device's format (binary b"FSA1" or a JSON
    /// line; module documentation).
    #[arg(long)]
    pub assess_events: bool,
    /// Speak OpenIGTLink instead of UDP: listen for peers (3D Slicer's
    /// OpenIGTLinkIF as a client, ...) on this TCP address (default
    /// 127.0.0.1:18944, loopback only).
    #[arg(long, num_args = 0..=1, default_missing_value = "127.0.0.1:18944", help_heading = "OpenIGTLink")]
    pub igtl_listen: Option<SocketAddr>,
    /// Speak OpenIGTLink instead of UDP: connect to the OpenIGTLink server
    /// at HOST:PORT (PLUS, or Slicer's OpenIGTLinkIF as a server), and
    /// reconnect when it goes away.
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_connect: Option<String>,
    /// DEVICE=INSTRUMENT: poses of OpenIGTLink device DEVICE drive
    /// INSTRUMENT (repeatable; a device not mapped drives the instrument of
    /// its own name).
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_map: Vec<String>,
    /// The sender's frame to the scene frame: a 4x4 homogeneous transform,
    /// 16 numbers row major (commas or blanks), in the sender's units, its
    /// 3x3 part a rotation (default identity).
    #[arg(long, allow_hyphen_values = true, help_heading = "OpenIGTLink")]
    pub igtl_registration: Option<String>,
    /// Metres per unit of the sender's positions (0.001: millimetres, as
    /// Slicer and PLUS send).
    #[arg(long, default_value_t = 0.001, help_heading = "OpenIGTLink")]
    pub igtl_unit_m: f64,
    /// Device name of the deformed surface's POLYDATA messages.
    #[arg(long, default_value = "fissure_surface", help_heading = "OpenIGTLink")]
    pub igtl_surface_device: String,
    /// Send no surface (no POLYDATA; the bridge still watches the frames
    /// for the ties' and the assessment's STATUS messages unless
    /// `--igtl-no-ties` and `--igtl-no-assess` are given too).
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_no_surface: bool,
    /// Send the triangles with every POLYDATA, not only with a peer's first.
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_topology_every: bool,
    /// Device name of the STATUS messages announcing each tie (arachnoid
    /// trabecula, bridging vessel) cut or torn, in scenes with ties.
    #[arg(long, default_value = "fissure_ties", help_heading = "OpenIGTLink")]
    pub igtl_ties_device: String,
    /// Send no tie STATUS messages.
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_no_ties: bool,
    /// Device name of the STATUS messages announcing a measure of the
    /// assessment (retraction pressure, tissue strain) reaching its warning
    /// level (`ASSESS_WARN`) or its failing level (`ASSESS_FAIL`).
    #[arg(long, default_value = "fissure_assess", help_heading = "OpenIGTLink")]
    pub igtl_assess_device: String,
    /// Send no assessment STATUS messages.
    #[arg(long, help_heading = "OpenIGTLink")]
    pub igtl_no_assess: bool,
}

impl BridgeArgs {
    /// The OpenIGTLink options, when `--igtl-listen` or `--igtl-connect`
    /// is given.
    pub fn igtl_options(&self) -> anyhow::Result<Option<igtl::IgtlOptions>> {
        if self.igtl_listen.is_none() && self.igtl_connect.is_none() {
            let given = [
                ("--igtl-map", !self.igtl_map.is_empty()),
                ("--igtl-registration", self.igtl_registration.is_some()),
                ("--igtl-unit-m", self.igtl_unit_m != 0.001),
                (
                    "--igtl-surface-device",
                    self.igtl_surface_device != "fissure_surface",
                ),
                ("--igtl-no-surface", self.igtl_no_surface),
                ("--igtl-topology-every", self.igtl_topology_every),
                (
                    "--igtl-ties-device",
                    self.igtl_ties_device != "fissure_ties",
                ),
                ("--igtl-no-ties", self.igtl_no_ties),
                (
                    "--igtl-assess-device",
                    self.igtl_assess_device != "fissure_assess",
                ),
                ("--igtl-no-assess", self.igtl_no_assess),
            ];
            if let Some((flag, _)) = given.iter().find(|(_, g)| *g) {
                bail!(
                    "{flag} needs --igtl-listen or --igtl-connect (without them the bridge speaks UDP)"
                );
            }
            return Ok(None);
        }
        let registration = match &self.igtl_registration {
            Some(r) => igtl::Registration::parse(r, self.igtl_unit_m)
                .map_err(|e| anyhow::anyhow!("--igtl-registration: {e}"))?,
            None => {
                igtl::Registration::parse("1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1", self.igtl_unit_m)
                    .map_err(|e| anyhow::anyhow!("--igtl-unit-m: {e}"))?
            }
        };
        Ok(Some(igtl::IgtlOptions {
            listen: self.igtl_listen,
            connect: self.igtl_connect.clone(),
            map: igtl::parse_map(&self.igtl_map)?,
            registration,
            surface_device: (!self.igtl_no_surface).then(|| self.igtl_surface_device.clone()),
            topology_every: self.igtl_topology_every,
            ties_device: (!self.igtl_no_ties).then(|| self.igtl_ties_device.clone()),
            assess_device: (!self.igtl_no_assess).then(|| self.igtl_assess_device.clone()),
        }))
    }
}

/// Options of the UDP bridge beyond its addresses.
#[derive(Debug, Clone, Copy, Default)]
pub struct UdpOptions {
    /// Send every device that has sent a pose a datagram per tie cut or
    /// torn (scenes with ties), in the device's format.
    pub tie_events: bool,
    /// Send every device that has sent a pose a datagram when a measure of
    /// the assessment first reaches its warning or its failing level.
    pub assess_events: bool,
}

impl Bridge {
    /// Connects to `server`, claims `instruments` (every instrument of the
    /// scene when empty) and listens on `listen`.
    pub async fn start(
        server: &str,
        listen: SocketAddr,
        instruments: &[String],
        token: Option<&str>,
    ) -> anyhow::Result<Self> {
        Self::start_with(server, listen, instruments, token, UdpOptions::default()).await
    }

    /// [`Self::start`] with `options`.
    pub async fn start_with(
        server: &str,
        listen: SocketAddr,
        instruments: &[String],
        token: Option<&str>,
        options: UdpOptions,
    ) -> anyhow::Result<Self> {
        let mut client = connect(server).await?;
        let names = instrument_names(&mut client, instruments).await?;
        if names.len() > 256 {
            bail!("at most 256 instruments can be bridged (the index is one byte)");
        }
        let socket = Arc::new(
            UdpSocket::bind(listen)
                .await
                .with_context(|| format!("binding UDP {listen}"))?,
        );
        let local_addr = socket.local_addr()?;
        let counters = Arc::new(Counters::default());
        let lanes = Lanes::open(&mut client, &names, token, || {
            UdpAnswers::new(socket.clone(), counters.clone())
        })
        .await?;
        let (stop, stopped) = tokio::sync::watch::channel(false);
        // Devices to tell of ties cut or torn and of the assessment's
        // alerts (address and format), when asked (ties: when the scene has
        // them).
        let ties = options.tie_events && ties::scene_has_ties(&mut client).await?;
        let alerts = if options.assess_events {
            Some(live_alerts(&mut client).await?)
        } else {
            None
        };
        let recipients: Option<Recipients> = if ties || alerts.is_some() {
            let frames = client
                .watch(pb::WatchRequest {
                    include_positions: false,
                })
                .await
                .context("Watch")?
                .into_inner();
            let r = Recipients::default();
            tokio::spawn(event_loop(
                frames,
                EventSinks {
                    socket: socket.clone(),
                    recipients: r.clone(),
                    names: names.clone(),
                    counters: counters.clone(),
                },
                ties,
                alerts,
                stopped.clone(),
            ));
            Some(r)
        } else {
            None
        };
        let task = tokio::spawn(serve(lanes, socket, counters.clone(), recipients, stopped));
        Ok(Self {
            local_addr,
            counters,
            stop,
            task,
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> BridgeStats {
        self.counters.snapshot()
    }

    /// Stops listening, closes the haptic streams (releasing the claims)
    /// and returns the final counters.
    pub async fn stop(self) -> anyhow::Result<BridgeStats> {
        let _ = self.stop.send(true);
        self.task.await.context("the bridge task panicked")??;
        Ok(self.counters.snapshot())
    }

    /// Waits until the bridge ends by itself (a receive error).
    pub async fn wait(&mut self) -> anyhow::Result<()> {
        (&mut self.task).await.context("the bridge task panicked")?
    }
}

/// The instruments to bridge: `instruments`, or every instrument of the
/// scene (in the scene's order) when it is empty.
pub(crate) async fn instrument_names(
    client: &mut fissure_proto::v1::fissure_client::FissureClient<tonic::transport::Channel>,
    instruments: &[String],
) -> anyhow::Result<Vec<String>> {
    let names: Vec<String> = if instruments.is_empty() {
        client
            .get_scene(pb::GetSceneRequest {})
            .await
            .context("GetScene")?
            .into_inner()
            .instruments
            .into_iter()
            .map(|i| i.name)
            .collect()
    } else {
        instruments.to_vec()
    };
    if names.is_empty() {
        bail!("the scene has no instrument to bridge");
    }
    Ok(names)
}

/// The UDP loop: parses each datagram, forwards its pose on its
/// instrument's lane, or answers `not forwarded` at once; then closes the
/// lanes.
async fn serve(
    lanes: Lanes<Pending>,
    socket: Arc<UdpSocket>,
    counters: Arc<Counters>,
    recipients: Option<Recipients>,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) -> anyhow::Result<()> {
    let mut buf = [0u8; MAX_DATAGRAM + 1];
    let mut answers = UdpAnswers::new(socket.clone(), counters.clone());
    loop {
        let (n, from) = tokio::select! {
            r = socket.recv_from(&mut buf) => match r {
                Ok(x) => x,
                // ICMP "port unreachable" of an earlier answer to a
                // device that went away: not fatal.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => continue,
                Err(e) => return Err(e).context("receiving a datagram"),
            },
            _ = stopped.changed() => break,
        };
        counters.received.fetch_add(1, Ordering::Relaxed);
        // `buf` holds one byte more than the limit, so a longer datagram
        // arrives cut to `MAX_DATAGRAM + 1` bytes and is refused as too long.
        let d = match parse_datagram(&buf[..n]) {
            Ok(d) => d,
            Err(e) => {
                let bad = counters.bad.fetch_add(1, Ordering::Relaxed);
                if bad < 10 || bad.is_power_of_two() {
                    tracing::warn!("datagram from {from} dropped: {e} ({} so far)", bad + 1);
                }
                continue;
            }
        };
        if let Some(r) = &recipients {
            r.note(from, d.format);
        }
        let index = match d.instrument {
            InstrumentRef::Index(i) => Some(i as usize).filter(|&i| i < lanes.len()),
            InstrumentRef::Name(n) => lanes.index_of(n),
        };
        let to = Pending {
            to: from,
            format: d.format,
        };
        let forwarded = index.is_some_and(|i| lanes.forward(i, pose_sample(&d), to));
        if forwarded {
            counters.forwarded.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        counters.not_forwarded.fetch_add(1, Ordering::Relaxed);
        let instrument = match d.instrument {
            InstrumentRef::Index(i) => i,
            InstrumentRef::Name(_) => index.unwrap_or(255) as u8,
        };
        let f = ForceDatagram::empty(instrument, Status::NotForwarded as u16, d.sequence, d.t_s);
        let name = match (index, d.instrument) {
            (Some(i), _) => lanes.name(i),
            (None, InstrumentRef::Name(n)) => n,
            (None, InstrumentRef::Index(_)) => "",
        };
        let msg = if index.is_none() {
            "unknown instrument"
        } else {
            "the instrument's stream is full or closed"
        };
        answers.send(to, &f, name, Some(msg)).await;
    }
    // Close the streams (releases the claims) and let the readers answer
    // what is still in flight.
    lanes.close().await;
    Ok(())
}

/// The devices that have sent a pose, with their format: the recipients
/// of the tie datagrams.
#[derive(Debug, Clone, Default)]
struct Recipients(Arc<std::sync::Mutex<std::collections::HashMap<SocketAddr, Format>>>);

impl Recipients {
    /// Notes a device (no allocation once it is known).
    fn note(&self, from: SocketAddr, format: Format) {
        let mut m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        match m.get_mut(&from) {
            Some(f) => *f = format,
            None => {
                m.insert(from, format);
            }
        }
    }

    fn list(&self) -> Vec<(SocketAddr, Format)> {
        let m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        m.iter().map(|(a, f)| (*a, *f)).collect()
    }
}

/// The assessment's live alerts against the server's scene's thresholds
/// (both bridges tell their devices of them).
pub(crate) async fn live_alerts(
    client: &mut pb::fissure_client::FissureClient<tonic::transport::Channel>,
) -> anyhow::Result<crate::client::report::assess::LiveAlerts> {
    let scene = client
        .get_scene(pb::GetSceneRequest {})
        .await
        .context("GetScene")?
        .into_inner();
    let (thresholds, _) = crate::client::report::assess::thresholds(Some(&scene));
    Ok(crate::client::report::assess::LiveAlerts::new(thresholds))
}

/// Where [`event_loop`] sends: the bridge's socket, to its recipients, with
/// the bridged instruments' names (for their indices).
struct EventSinks {
    socket: Arc<UdpSocket>,
    recipients: Recipients,
    names: Vec<String>,
    counters: Arc<Counters>,
}

impl EventSinks {
    /// Sends `bin` to the binary recipients and `json` to the JSON ones;
    /// counts each datagram sent in `sent`.
    async fn send(&self, bin: &[u8], json: &[u8], sent: &AtomicU64, what: &str) {
        for (to, format) in self.recipients.list() {
            let bytes: &[u8] = match format {
                Format::Binary => bin,
                Format::Json => json,
            };
            match self.socket.send_to(bytes, to).await {
                Ok(_) => {
                    sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => tracing::warn!("{what} to {to}: {e}"),
            }
        }
    }
}

/// Reads deformation frames and tells every recipient of each tie cut or
/// torn (with `ties`) and of each measure of the assessment reaching a
/// level (with `alerts`).
async fn event_loop(
    mut frames: tonic::Streaming<pb::DeformationFrame>,
    sinks: EventSinks,
    ties: bool,
    mut alerts: Option<crate::client::report::assess::LiveAlerts>,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) {
    let mut notices = ties::TieNotices::default();
    let mut bin = [0u8; TIE_LEN];
    let mut alert_bin = [0u8; ALERT_LEN];
    let mut json = Vec::new();
    let index = |name: &str| sinks.names.iter().position(|x| x == name);
    loop {
        let frame = tokio::select! {
            f = frames.message() => f,
            _ = stopped.changed() => return,
        };
        let f = match frame {
            Ok(Some(f)) => f,
            Ok(None) => return,
            Err(e) => {
                tracing::warn!("UDP bridge: the watch stream for events ended: {e}");
                return;
            }
        };
        if let Some(live) = alerts.as_mut() {
            for a in live.frame(&f) {
                let i = a.instrument.as_deref().and_then(index);
                encode_alert(&AlertDatagram::of(&a, i), &mut alert_bin);
                if encode_alert_json(&a, &mut json).is_ok() {
                    sinks
                        .send(
                            &alert_bin,
                            &json,
                            &sinks.counters.assess_events,
                            "assessment alert",
                        )
                        .await;
                }
            }
        }
        let Some(summary) = f.ties.as_ref().filter(|_| ties) else {
            continue;
        };
        for n in notices.of(summary) {
            encode_tie(&TieDatagram::of(&n, index(&n.instrument)), &mut bin);
            if encode_tie_json(&n, &mut json).is_ok() {
                sinks
                    .send(&bin, &json, &sinks.counters.tie_events, "tie event")
                    .await;
            }
        }
    }
}

/// The UDP protocol's answers: a force datagram in the pose's format, back
/// to the pose's sender (its buffers allocated once).
struct UdpAnswers {
    socket: Arc<UdpSocket>,
    counters: Arc<Counters>,
    bin: [u8; FORCE_LEN],
    json: Vec<u8>,
}

impl UdpAnswers {
    fn new(socket: Arc<UdpSocket>, counters: Arc<Counters>) -> Self {
        Self {
            socket,
            counters,
            bin: [0u8; FORCE_LEN],
            json: Vec::with_capacity(512),
        }
    }

    /// Sends `f` (and, in JSON, `name` and `message`) to `to`.
    async fn send(&mut self, to: Pending, f: &ForceDatagram, name: &str, message: Option<&str>) {
        let bytes: &[u8] = match to.format {
            Format::Binary => {
                encode_force(f, &mut self.bin);
                &self.bin
            }
            Format::Json => {
                if encode_force_json(f, name, message, &mut self.json).is_err() {
                    return;
                }
                &self.json
            }
        };
        match self.socket.send_to(bytes, to.to).await {
            Ok(_) => {
                self.counters.answered.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::warn!("answer to {}: {e}", to.to),
        }
    }
}

impl Answers<Pending> for UdpAnswers {
    async fn answer(&mut self, index: usize, name: &str, to: Pending, sample: pb::ForceSample) {
        let v = |v: &Option<pb::Vec3>| v.as_ref().map_or([0.0; 3], |v| [v.x, v.y, v.z]);
        let rejected = sample.rejection.is_some();
        if rejected {
            self.counters.rejected.fetch_add(1, Ordering::Relaxed);
        }
        let f = ForceDatagram {
            instrument: index as u8,
            status: if rejected {
                Status::Rejected as u16
            } else {
                Status::Ok as u16
            },
            sequence: sample.sequence,
            t_s: sample.t_s,
            force_n: v(&sample.force_n),
            torque_nm: v(&sample.torque_nm),
            contact_count: sample.contact_count,
            safety_flags: sample.safety_flags,
            model_frame: sample.model_frame,
            model_age_s: sample.model_age_s,
            server_compute_us: sample.server_compute_us,
        };
        let message = sample.rejection.as_ref().map(|r| r.message.as_str());
        self.send(to, &f, name, message).await;
    }
}

/// Runs the OpenIGTLink bridge until Ctrl-C or `--duration-s`.
async fn run_igtl(args: &BridgeArgs, options: &igtl::IgtlOptions) -> anyhow::Result<()> {
    let bridge = igtl::IgtlBridge::start(
        &args.server,
        &args.instrument,
        args.token.as_deref(),
        options,
    )
    .await?;
    if let Some(a) = bridge.local_addr {
        eprintln!(
            "OpenIGTLink: listening on TCP {a}, bridging to {}",
            args.server
        );
    }
    if let Some(c) = &options.connect {
        eprintln!(
            "OpenIGTLink: connecting to {c}, bridging to {}",
            args.server
        );
    }
    let limit = async {
        match args.duration_s {
            Some(d) => tokio::time::sleep(std::time::Duration::from_secs_f64(d.max(0.0))).await,
            None => std::future::pending().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = limit => {}
    }
    let s = bridge.stop().await?;
    eprintln!(
        "OpenIGTLink: connections {}, messages received {}, bad {}, ignored {}, poses forwarded {}, not forwarded {}, rejected by the server {}, answered {}, STATUS sent {}, answers dropped {}, surface frames {}, POLYDATA sent {}",
        s.connections,
        s.received,
        s.bad,
        s.ignored,
        s.forwarded,
        s.not_forwarded,
        s.rejected,
        s.answered,
        s.statuses,
        s.dropped,
        s.surface_frames,
        s.polydata_sent
    );
    Ok(())
}

/// Runs `fissure bridge` until Ctrl-C or `--duration-s`: UDP, or
/// OpenIGTLink with `--igtl-listen` / `--igtl-connect` (the instruments are
/// claimed by one or the other).
pub async fn run(args: &BridgeArgs) -> anyhow::Result<()> {
    if let Some(options) = args.igtl_options()? {
        return run_igtl(args, &options).await;
    }
    run_udp(args).await.map(|_| ())
}

async fn run_udp(args: &BridgeArgs) -> anyhow::Result<BridgeStats> {
    let mut bridge = Bridge::start_with(
        &args.server,
        args.listen,
        &args.instrument,
        args.token.as_deref(),
        UdpOptions {
            tie_events: args.tie_events,
            assess_events: args.assess_events,
        },
    )
    .await?;
    eprintln!(
        "bridging UDP {} to {} (binary b\"FSP1\" or JSON poses; see `fissure bridge --help`)",
        bridge.local_addr, args.server
    );
    let limit = async {
        match args.duration_s {
            Some(d) => tokio::time::sleep(std::time::Duration::from_secs_f64(d.max(0.0))).await,
            None => std::future::pending().await,
        }
    };
    tokio::select! {
        r = bridge.wait() => { r?; bail!("the bridge stopped"); }
        _ = tokio::signal::ctrl_c() => {}
        _ = limit => {}
    }
    let stats = bridge.stop().await?;
    eprintln!(
        "datagrams received {}, bad {}, poses forwarded {}, not forwarded {}, rejected by the server {}, answers sent {}, tie events sent {}, assessment alerts sent {}",
        stats.received,
        stats.bad,
        stats.forwarded,
        stats.not_forwarded,
        stats.rejected,
        stats.answered,
        stats.tie_events,
        stats.assess_events
    );
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: BridgeArgs,
    }

    fn args(line: &[&str]) -> BridgeArgs {
        Cli::try_parse_from(std::iter::once("bridge").chain(line.iter().copied()))
            .expect("the flags parse")
            .args
    }

    #[test]
    fn igtl_listen_alone_is_loopback_on_the_slicer_port() {
        let o = args(&["--igtl-listen", "--igtl-map", "Tracker=left"])
            .igtl_options()
            .unwrap()
            .expect("OpenIGTLink");
        assert_eq!(o.listen, Some("127.0.0.1:18944".parse().unwrap()));
        assert_eq!(o.map["Tracker"], "left");
        assert_eq!(o.registration, igtl::Registration::default());
        assert_eq!(o.surface_device.as_deref(), Some("fissure_surface"));
        // No OpenIGTLink flag: the UDP bridge.
        assert!(args(&[]).igtl_options().unwrap().is_none());
    }

    #[test]
    fn igtl_flags_without_a_peer_are_refused() {
        for line in [
            &["--igtl-map", "A=left"][..],
            &["--igtl-no-surface"],
            &["--igtl-unit-m", "1"],
        ] {
            let e = args(line).igtl_options().unwrap_err().to_string();
            assert!(e.contains("needs --igtl-listen or --igtl-connect"), "{e}");
        }
        // A registration with negative numbers parses as one value.
        let o = args(&[
            "--igtl-connect",
            "plus:18944",
            "--igtl-registration",
            "-1 0 0 -5  0 -1 0 0  0 0 1 0  0 0 0 1",
        ])
        .igtl_options()
        .unwrap()
        .expect("OpenIGTLink");
        assert_eq!(o.registration.translation.x, -5.0);
    }
}
