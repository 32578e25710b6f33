//! `fissure bridge --igtl-listen` / `--igtl-connect`: the bridge speaking
//! OpenIGTLink over TCP, for 3D Slicer (OpenIGTLinkIF), PLUS and any other
//! OpenIGTLink peer. The gRPC side is the UDP bridge's ([`super::Lanes`]: one
//! haptic stream per claimed instrument).
//!
//! # Messages
//!
//! **In** (from any peer): TRANSFORM and POSITION. The device name picks
//! the instrument (`--igtl-map DEVICE=INSTRUMENT`; a device without a
//! mapping drives the instrument of its own name). The message is the pose
//! of the instrument's handle frame in the sender's frame, in the sender's
//! units (millimetres for Slicer and PLUS). Other message types
//! (GET_STATUS, CAPABILITY, IMAGE, ...) are read past and counted as
//! ignored; messages that do not parse (wrong CRC, bad sizes, a matrix that
//! is not a rotation, ...) are dropped, counted and named in the log. A
//! header that does not parse, or declares a body over
//! [`codec::MAX_BODY_BYTES`], ends that connection (the stream's framing is
//! lost).
//!
//! **Out**, to the peer that sent the pose, for each pose answered:
//! * SENSOR `<instrument>_force`: 3 values, the force on the instrument, N
//!   (unit field: newton);
//! * SENSOR `<instrument>_torque`: 3 values, the torque about the handle
//!   point, N m (unit field: newton metre);
//!
//!   both in the sender's frame, with the pose's header timestamp (so a
//!   peer can pair them with its poses);
//! * STATUS (device: the pose's device) when the server rejects the pose
//!   (code 2, subcode the gRPC code, error name `POSE_REJECTED`, the
//!   server's reason), when the bridge cannot forward it (code 4
//!   `UNKNOWN_DEVICE`, once per device and connection, or code 6
//!   `LANE_FULL`), and whenever the instrument's safety flags change (code 1,
//!   subcode the `fissure.v1.SafetyFlag` bits, error name `SAFETY`, the flag
//!   names).
//!
//! To every peer, in scenes with ties (arachnoid trabeculae, bridging
//! vessels): a STATUS `--igtl-ties-device` (default `fissure_ties`) for each
//! tie cut or torn, as the deformation frames report it ([`tie_status`]):
//! subcode the tie's index, error name `TIE_CUT`, `TIE_TORN` or (code 2, an
//! injury) `VESSEL_TORN`, and a text with the tie's kind, the instrument,
//! the simulation time, the place (sender frame and units) and the strain;
//! `TIE_RELEASED` for a tie whose event was in a frame the bridge did not
//! receive (the frames' cumulative list of released ties names it).
//!
//! To every peer: POLYDATA `--igtl-surface-device` (default
//! `fissure_surface`), the deformed brain surface at the deformation rate,
//! vertex positions in the sender's frame and units; the triangles (a
//! POLYGONS cell array) with a peer's first POLYDATA only, or with every one
//! under `--igtl-topology-every` (for receivers that rebuild the mesh from
//! each message, as 3D Slicer's OpenIGTLinkIO converter does). A peer slower than the deformation rate gets the newest
//! frame when it is ready for one; force answers are never queued behind
//! surfaces.
//!
//! # Frames, units and time
//!
//! `--igtl-registration` is the 4x4 homogeneous transform (16 numbers, row
//! major, the last row `0 0 0 1`, in the sender's units) from the sender's
//! frame to the scene frame; its 3x3 part must be a rotation. A sender
//! position `p` becomes the scene position `unit_m * (R p + t)` in metres
//! (`--igtl-unit-m`, default 0.001: millimetres) and a sender orientation
//! `Q` becomes `R Q`. Forces, torques and surface vertices go back through
//! the inverse: `f_sender = R^T f_scene`, `v_sender = R^T (v_scene / unit_m - t)`.
//!
//! A pose's time is its header timestamp less that of the first pose of its
//! instrument (so the server's stepped mode starts at 0); a sender that
//! puts 0 in the timestamp gets the time elapsed since its instrument's
//! first pose. A sender clock going back by more than [`CLOCK_RESTART_S`]
//! (a restarted sender) is rebased so that the instrument's time carries on
//! from its last pose; smaller steps back reach the server, which rejects
//! them. Sequence numbers are the bridge's, per instrument.

pub mod codec;

use super::ties::{TieHow, TieNotice, TieNotices};
use super::{Answers, Lanes, instrument_names};
use crate::client::replay::connect;
use anyhow::{Context, bail};
use codec::{
    Body, Cells, HEADER_LEN, IgtlError, StatusMsg, Unit, append_message, name_field, status_code,
    type_field, write_message,
};
use fissure_proto::v1 as pb;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};

/// The default OpenIGTLink port (Slicer's and PLUS's).
pub const DEFAULT_PORT: u16 = 18944;
/// Answers queued per peer before new ones are dropped (a peer that does
/// not read its socket must not hold up the force loop).
pub const PEER_QUEUE: usize = 4096;

/// The registration of the sender's frame to the scene frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    /// Rotation, sender to scene.
    pub rotation: Matrix3<f64>,
    /// Translation, sender units.
    pub translation: Vector3<f64>,
    /// Metres per sender unit.
    pub unit_m: f64,
}

impl Default for Registration {
    fn default() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
            unit_m: 0.001,
        }
    }
}

/// Why a registration was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    /// Not 16 numbers.
    #[error("expected 16 numbers (a 4x4 matrix, row major), got {0}")]
    Count(usize),
    /// A number that does not parse.
    #[error("{0:?} is not a number")]
    Number(String),
    /// The last row is not `0 0 0 1`.
    #[error("the last row must be 0 0 0 1")]
    LastRow,
    /// The 3x3 part is not a rotation.
    #[error("the 3x3 part is not a rotation (|R^T R - I| = {0:.2e}, det = {1:.6})")]
    NotRotation(f64, f64),
    /// The unit is not a positive finite number.
    #[error("the unit must be a positive number of metres, got {0}")]
    Unit(f64),
}

impl Registration {
    /// Parses 16 numbers (separated by commas and/or blanks), row major.
    pub fn parse(s: &str, unit_m: f64) -> Result<Self, RegistrationError> {
        if unit_m.is_nan() || unit_m <= 0.0 || unit_m.is_infinite() {
            return Err(RegistrationError::Unit(unit_m));
        }
        let v = s
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| {
                t.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| RegistrationError::Number(t.to_owned()))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        if v.len() != 16 {
            return Err(RegistrationError::Count(v.len()));
        }
        if v[12..] != [0.0, 0.0, 0.0, 1.0] {
            return Err(RegistrationError::LastRow);
        }
        let rotation = Matrix3::from_fn(|r, c| v[4 * r + c]);
        let err = (rotation.transpose() * rotation - Matrix3::identity())
            .abs()
            .max();
        let det = rotation.determinant();
        if err > 1e-6 || (det - 1.0).abs() > 1e-6 {
            return Err(RegistrationError::NotRotation(err, det));
        }
        Ok(Self {
            rotation,
            translation: Vector3::new(v[3], v[7], v[11]),
            unit_m,
        })
    }

    /// A sender position (sender units) in the scene, m.
    pub fn position_m(&self, p: [f64; 3]) -> [f64; 3] {
        let s = (self.rotation * Vector3::from(p) + self.translation) * self.unit_m;
        [s.x, s.y, s.z]
    }

    /// A sender orientation in the scene frame.
    pub fn orientation(&self, q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        rotation_quaternion(&self.rotation) * q
    }

    /// A scene vector (force, torque) in the sender's frame.
    pub fn vector_to_sender(&self, v: [f64; 3]) -> [f64; 3] {
        let s = self.rotation.transpose() * Vector3::from(v);
        [s.x, s.y, s.z]
    }

    /// A scene position, m, in the sender's frame and units.
    pub fn point_to_sender(&self, p_m: [f64; 3]) -> [f64; 3] {
        let s = self.rotation.transpose() * (Vector3::from(p_m) / self.unit_m - self.translation);
        [s.x, s.y, s.z]
    }
}

/// The quaternion of a rotation matrix (orthonormal within the codec's
/// 1e-3), in closed form and normalised. (nalgebra's `from_matrix` is an
/// iteration to machine precision that can take milliseconds on the f32
/// matrices of a tracker.)
pub fn rotation_quaternion(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let q = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(*m));
    UnitQuaternion::new_normalize(q.into_inner())
}

/// Options of the OpenIGTLink side of a bridge.
#[derive(Debug, Clone)]
pub struct IgtlOptions {
    /// Address to listen on (TCP), if any.
    pub listen: Option<SocketAddr>,
    /// `host:port` of an OpenIGTLink server to connect to (and reconnect to
    /// when it goes away), if any.
    pub connect: Option<String>,
    /// Device name to instrument name.
    pub map: HashMap<String, String>,
    /// Sender frame to scene frame.
    pub registration: Registration,
    /// Device name of the surface POLYDATA; `None`: no surface.
    pub surface_device: Option<String>,
    /// Send the triangles with every POLYDATA (not only a peer's first).
    pub topology_every: bool,
    /// Device name of the ties' STATUS messages (scenes with ties); `None`:
    /// none.
    pub ties_device: Option<String>,
    /// Device name of the STATUS messages of the assessment's alerts (a
    /// measure reaching its warning or failing level); `None`: none.
    pub assess_device: Option<String>,
}

impl Default for IgtlOptions {
    fn default() -> Self {
        Self {
            listen: None,
            connect: None,
            map: HashMap::new(),
            registration: Registration::default(),
            surface_device: Some("fissure_surface".to_owned()),
            topology_every: false,
            ties_device: Some("fissure_ties".to_owned()),
            assess_device: Some("fissure_assess".to_owned()),
        }
    }
}

/// Parses `--igtl-map DEVICE=INSTRUMENT` values.
pub fn parse_map(values: &[String]) -> anyhow::Result<HashMap<String, String>> {
    let mut map = HashMap::new();
    for v in values {
        let Some((d, i)) = v.split_once('=') else {
            bail!("--igtl-map {v:?}: expected DEVICE=INSTRUMENT");
        };
        if name_field::<20>(d).is_none() {
            bail!("--igtl-map {v:?}: a device name is at most 20 printable ASCII characters");
        }
        if map.insert(d.to_owned(), i.to_owned()).is_some() {
            bail!("--igtl-map: device {d:?} is mapped twice");
        }
    }
    Ok(map)
}

/// Counters of an OpenIGTLink bridge.
#[derive(Debug, Default)]
pub struct IgtlCounters {
    /// Peer connections accepted or made.
    pub connections: AtomicU64,
    /// Messages received (whole headers read).
    pub received: AtomicU64,
    /// Messages dropped as malformed (and headers that ended a connection).
    pub bad: AtomicU64,
    /// Messages of types the bridge does not read.
    pub ignored: AtomicU64,
    /// Poses forwarded to the server.
    pub forwarded: AtomicU64,
    /// Poses not forwarded (unknown device, lane full or closed).
    pub not_forwarded: AtomicU64,
    /// Poses the server rejected.
    pub rejected: AtomicU64,
    /// Poses answered with SENSOR messages.
    pub answered: AtomicU64,
    /// STATUS messages sent.
    pub statuses: AtomicU64,
    /// Answers dropped because their peer's queue was full or it left.
    pub dropped: AtomicU64,
    /// Deformation frames received from the server.
    pub surface_frames: AtomicU64,
    /// POLYDATA messages sent (all peers).
    pub polydata_sent: AtomicU64,
}

/// A snapshot of [`IgtlCounters`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct IgtlStats {
    /// Peer connections accepted or made.
    pub connections: u64,
    /// Messages received.
    pub received: u64,
    /// Messages dropped as malformed.
    pub bad: u64,
    /// Messages of types the bridge does not read.
    pub ignored: u64,
    /// Poses forwarded to the server.
    pub forwarded: u64,
    /// Poses not forwarded.
    pub not_forwarded: u64,
    /// Poses the server rejected.
    pub rejected: u64,
    /// Poses answered with SENSOR messages.
    pub answered: u64,
    /// STATUS messages sent.
    pub statuses: u64,
    /// Answers dropped (peer queue full or peer gone).
    pub dropped: u64,
    /// Deformation frames received.
    pub surface_frames: u64,
    /// POLYDATA messages sent.
    pub polydata_sent: u64,
}

impl IgtlCounters {
    fn snapshot(&self) -> IgtlStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        IgtlStats {
            connections: l(&self.connections),
            received: l(&self.received),
            bad: l(&self.bad),
            ignored: l(&self.ignored),
            forwarded: l(&self.forwarded),
            not_forwarded: l(&self.not_forwarded),
            rejected: l(&self.rejected),
            answered: l(&self.answered),
            statuses: l(&self.statuses),
            dropped: l(&self.dropped),
            surface_frames: l(&self.surface_frames),
            polydata_sent: l(&self.polydata_sent),
        }
    }

    /// Counts a malformed message and logs it (the first ten, then at
    /// powers of two).
    fn bad(&self, peer: SocketAddr, e: &IgtlError) {
        let bad = self.bad.fetch_add(1, Ordering::Relaxed);
        if bad < 10 || bad.is_power_of_two() {
            tracing::warn!(
                "OpenIGTLink message from {peer} dropped: {e} ({} so far)",
                bad + 1
            );
        }
    }
}

/// The answer of a pose in flight goes to peer `peer`, under the pose's
/// device name and timestamp.
#[derive(Debug, Clone, Copy)]
struct Pending {
    peer: u64,
    device: [u8; 20],
    timestamp: u64,
}

/// One peer's outgoing queue.
type PeerTx = tokio::sync::mpsc::Sender<Vec<u8>>;

/// What the readers, the answers and the writers share.
struct Shared {
    lanes: Lanes<Pending>,
    clocks: Vec<Mutex<LaneClock>>,
    map: HashMap<String, usize>,
    registration: Registration,
    counters: Arc<IgtlCounters>,
    peers: Arc<Mutex<HashMap<u64, PeerTx>>>,
    surface: tokio::sync::watch::Receiver<Option<Arc<SurfaceFrame>>>,
    topology: Arc<Cells>,
    surface_device: Option<[u8; 20]>,
    topology_every: bool,
    /// The ties' STATUS messages, encoded, to every peer.
    tie_statuses: tokio::sync::broadcast::Sender<Arc<Vec<u8>>>,
    next_peer: AtomicU64,
}

/// A sender clock going back by more than this is taken for a restarted
/// sender, s: the lane's time carries on from its last pose.
pub const CLOCK_RESTART_S: f64 = 1.0;

/// A lane's clock and sequence.
#[derive(Debug, Default)]
struct LaneClock {
    /// Header time that is the lane's time 0, s.
    epoch_s: Option<f64>,
    /// When the lane's first pose arrived (for senders without timestamps).
    start: Option<Instant>,
    /// The latest time given, s.
    last_s: f64,
    sequence: u64,
}

impl LaneClock {
    fn next(&mut self, header_s: f64) -> (f64, u64) {
        self.sequence += 1;
        let t_s = if header_s > 0.0 {
            let epoch = *self.epoch_s.get_or_insert(header_s);
            let t = header_s - epoch;
            if t < self.last_s - CLOCK_RESTART_S {
                // A restarted sender (PLUS, a tracker): carry on from the
                // last pose rather than have every pose rejected as going
                // back. Smaller steps back go to the server, which rejects
                // them and says so.
                tracing::info!(
                    "OpenIGTLink: a sender's clock went back {:.3} s; its poses carry on from the last one",
                    self.last_s - t
                );
                self.epoch_s = Some(header_s - self.last_s);
                self.last_s
            } else {
                t
            }
        } else {
            self.start
                .get_or_insert_with(Instant::now)
                .elapsed()
                .as_secs_f64()
        };
        self.last_s = self.last_s.max(t_s);
        (t_s, self.sequence)
    }
}

/// A deformed surface, in the sender's frame and units.
#[derive(Debug)]
pub struct SurfaceFrame {
    /// Deformation frame number.
    pub frame: u64,
    /// Vertex positions, flattened.
    pub points: Vec<f32>,
}

/// The OpenIGTLink answers of one lane.
struct IgtlAnswers {
    peers: Arc<Mutex<HashMap<u64, PeerTx>>>,
    counters: Arc<IgtlCounters>,
    registration: Registration,
    force_device: [u8; 20],
    torque_device: [u8; 20],
    last_flags: u32,
}

fn status_message(out: &mut Vec<u8>, device: [u8; 20], timestamp: u64, s: &StatusMsg) {
    append_message(out, type_field("STATUS"), device, timestamp, |o| {
        codec::status_content(s, o)
    });
}

/// Names of the safety flags set in `flags`: the proto's `SafetyFlag` names
/// without their `SAFETY_FLAG_` prefix (the proto is the one list), and the
/// bits it does not define in hexadecimal.
pub fn flag_names(flags: u32) -> String {
    if flags == 0 {
        return "none".to_owned();
    }
    let mut v: Vec<String> = Vec::new();
    let mut rest = 0u32;
    for bit in 0..32 {
        let b = 1u32 << bit;
        if flags & b == 0 {
            continue;
        }
        match i32::try_from(b)
            .ok()
            .and_then(|b| pb::SafetyFlag::try_from(b).ok())
        {
            Some(f) => v.push(
                f.as_str_name()
                    .trim_start_matches("SAFETY_FLAG_")
                    .to_owned(),
            ),
            None => rest |= b,
        }
    }
    if rest != 0 {
        v.push(format!("{rest:#x}"));
    }
    v.join("|")
}

impl Answers<Pending> for IgtlAnswers {
    async fn answer(&mut self, _index: usize, _name: &str, to: Pending, s: pb::ForceSample) {
        let v = |v: &Option<pb::Vec3>| v.as_ref().map_or([0.0; 3], |v| [v.x, v.y, v.z]);
        // Both SENSOR messages (and a STATUS) in one buffer: one write, and
        // the one allocation of an answer.
        let mut out = Vec::with_capacity(2 * (HEADER_LEN + 58) + 128);
        let f = self.registration.vector_to_sender(v(&s.force_n));
        let t = self.registration.vector_to_sender(v(&s.torque_nm));
        for (device, unit, data) in [
            (self.force_device, Unit::newton(), f),
            (self.torque_device, Unit::newton_meter(), t),
        ] {
            append_message(&mut out, type_field("SENSOR"), device, to.timestamp, |o| {
                codec::sensor_content(0, unit.pack(), &data, o)
            });
        }
        let mut statuses = 0;
        if let Some(r) = &s.rejection {
            self.counters.rejected.fetch_add(1, Ordering::Relaxed);
            status_message(
                &mut out,
                to.device,
                to.timestamp,
                &StatusMsg {
                    code: status_code::UNKNOWN_ERROR,
                    subcode: r.code as i64,
                    error_name: "POSE_REJECTED".into(),
                    message: r.message.clone(),
                },
            );
            statuses += 1;
        } else if s.safety_flags != self.last_flags {
            self.last_flags = s.safety_flags;
            status_message(
                &mut out,
                to.device,
                to.timestamp,
                &StatusMsg {
                    code: status_code::OK,
                    subcode: s.safety_flags as i64,
                    error_name: "SAFETY".into(),
                    message: flag_names(s.safety_flags),
                },
            );
            statuses += 1;
        }
        let tx = self
            .peers
            .lock()
            .expect("peers lock")
            .get(&to.peer)
            .cloned();
        match tx.map(|tx| tx.try_send(out)) {
            Some(Ok(())) => {
                self.counters.answered.fetch_add(1, Ordering::Relaxed);
                self.counters
                    .statuses
                    .fetch_add(statuses, Ordering::Relaxed);
            }
            _ => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// A running OpenIGTLink bridge.
pub struct IgtlBridge {
    /// The TCP address it listens on (with `listen`).
    pub local_addr: Option<SocketAddr>,
    /// Its counters.
    pub counters: Arc<IgtlCounters>,
    stop: tokio::sync::watch::Sender<bool>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    shared: Arc<Shared>,
}

impl IgtlBridge {
    /// Connects to `server`, claims `instruments` (every instrument of the
    /// scene when empty), subscribes to the deformation (unless the surface
    /// is off) and listens and/or connects as `options` say.
    pub async fn start(
        server: &str,
        instruments: &[String],
        token: Option<&str>,
        options: &IgtlOptions,
    ) -> anyhow::Result<Self> {
        if options.listen.is_none() && options.connect.is_none() {
            bail!("an OpenIGTLink bridge needs --igtl-listen or --igtl-connect");
        }
        let mut client = connect(server).await?;
        let names = instrument_names(&mut client, instruments).await?;
        let mut map = HashMap::new();
        for (i, n) in names.iter().enumerate() {
            map.insert(n.clone(), i);
        }
        for (device, instrument) in &options.map {
            let Some(i) = names.iter().position(|n| n == instrument) else {
                bail!(
                    "--igtl-map {device}={instrument}: no such instrument is bridged ({names:?})"
                );
            };
            map.insert(device.clone(), i);
        }
        let mut devices = Vec::with_capacity(names.len());
        for n in &names {
            let f = name_field::<20>(&format!("{n}_force"));
            let t = name_field::<20>(&format!("{n}_torque"));
            let (Some(f), Some(t)) = (f, t) else {
                bail!(
                    "instrument {n:?}: its SENSOR device names ({n}_force, {n}_torque) must be at most 20 ASCII characters"
                );
            };
            devices.push((f, t));
        }
        let surface_device = match &options.surface_device {
            Some(d) => Some(name_field::<20>(d).with_context(|| {
                format!("--igtl-surface-device {d:?}: at most 20 printable ASCII characters")
            })?),
            None => None,
        };
        let counters = Arc::new(IgtlCounters::default());
        let peers: Arc<Mutex<HashMap<u64, PeerTx>>> = Arc::default();
        let mut lane = 0usize;
        let lanes = Lanes::open(&mut client, &names, token, || {
            let (force_device, torque_device) = devices[lane];
            lane += 1;
            IgtlAnswers {
                peers: peers.clone(),
                counters: counters.clone(),
                registration: options.registration,
                force_device,
                torque_device,
                last_flags: 0,
            }
        })
        .await?;
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let (surface_tx, surface_rx) = tokio::sync::watch::channel(None);
        let mut tasks = Vec::new();
        let mut topology = Cells::default();
        let ties_device = match &options.ties_device {
            Some(d) => Some(name_field::<20>(d).with_context(|| {
                format!("--igtl-ties-device {d:?}: at most 20 printable ASCII characters")
            })?),
            None => None,
        };
        let (tie_tx, _) = tokio::sync::broadcast::channel(TIE_QUEUE);
        let has_ties = ties_device.is_some() && super::ties::scene_has_ties(&mut client).await?;
        let assess = match &options.assess_device {
            Some(d) => {
                let device = name_field::<20>(d).with_context(|| {
                    format!("--igtl-assess-device {d:?}: at most 20 printable ASCII characters")
                })?;
                Some((device, super::live_alerts(&mut client).await?))
            }
            None => None,
        };
        if surface_device.is_some() {
            let s = client
                .get_surface(pb::GetSurfaceRequest {})
                .await
                .context("GetSurface")?
                .into_inner();
            let tris: Vec<[u32; 3]> = s
                .triangles
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect();
            topology = Cells::triangles(&tris);
        }
        if surface_device.is_some() || has_ties || assess.is_some() {
            let stream = client
                .watch(pb::WatchRequest {
                    include_positions: surface_device.is_some(),
                })
                .await
                .context("Watch")?
                .into_inner();
            tasks.push(tokio::spawn(surface_loop(
                stream,
                surface_tx,
                FrameOutputs {
                    registration: options.registration,
                    ties_device: ties_device.filter(|_| has_ties),
                    assess,
                    tie_statuses: tie_tx.clone(),
                    counters: counters.clone(),
                },
                stopped.clone(),
            )));
        }
        let shared = Arc::new(Shared {
            lanes,
            clocks: names.iter().map(|_| Mutex::default()).collect(),
            map,
            registration: options.registration,
            counters: counters.clone(),
            peers,
            surface: surface_rx,
            topology: Arc::new(topology),
            surface_device,
            topology_every: options.topology_every,
            tie_statuses: tie_tx,
            next_peer: AtomicU64::new(0),
        });
        let mut local_addr = None;
        if let Some(addr) = options.listen {
            let listener = TcpListener::bind(addr)
                .await
                .with_context(|| format!("binding OpenIGTLink TCP {addr}"))?;
            local_addr = Some(listener.local_addr()?);
            tasks.push(tokio::spawn(accept_loop(
                listener,
                shared.clone(),
                stopped.clone(),
            )));
        }
        if let Some(to) = &options.connect {
            tasks.push(tokio::spawn(connect_loop(
                to.clone(),
                shared.clone(),
                stopped.clone(),
            )));
        }
        Ok(Self {
            local_addr,
            counters,
            stop,
            tasks,
            shared,
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> IgtlStats {
        self.counters.snapshot()
    }

    /// Stops listening and connecting, closes the peers and the haptic
    /// streams (releasing the claims) and returns the final counters.
    pub async fn stop(self) -> anyhow::Result<IgtlStats> {
        let _ = self.stop.send(true);
        for t in self.tasks {
            t.await.context("an OpenIGTLink bridge task panicked")?;
        }
        // The connection tasks hold the last other references.
        let shared = match Arc::try_unwrap(self.shared) {
            Ok(s) => s,
            Err(_) => bail!("an OpenIGTLink connection outlived the bridge"),
        };
        shared.lanes.close().await;
        Ok(self.counters.snapshot())
    }
}

/// The ties' STATUS messages queued for each peer before the oldest are
/// dropped (a peer that does not read its socket).
pub const TIE_QUEUE: usize = 1024;

/// What [`surface_loop`] makes of the frames besides the surface.
struct FrameOutputs {
    registration: Registration,
    ties_device: Option<[u8; 20]>,
    /// The assessment's device and its alerts.
    assess: Option<([u8; 20], crate::client::report::assess::LiveAlerts)>,
    tie_statuses: tokio::sync::broadcast::Sender<Arc<Vec<u8>>>,
    counters: Arc<IgtlCounters>,
}

/// Reads deformation frames and publishes them, converted to the sender's
/// frame, for the writers; with a ties device, each tie cut or torn as a
/// STATUS to every peer; with an assessment device, each measure reaching
/// a level.
async fn surface_loop(
    mut stream: tonic::Streaming<pb::DeformationFrame>,
    tx: tokio::sync::watch::Sender<Option<Arc<SurfaceFrame>>>,
    mut out: FrameOutputs,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) {
    let registration = out.registration;
    let mut notices = TieNotices::default();
    loop {
        let frame = tokio::select! {
            f = stream.message() => f,
            _ = stopped.changed() => return,
        };
        let f = match frame {
            Ok(Some(f)) => f,
            Ok(None) => return,
            Err(e) => {
                tracing::warn!("OpenIGTLink surface: the watch stream ended: {e}");
                return;
            }
        };
        out.counters.surface_frames.fetch_add(1, Ordering::Relaxed);
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        if let Some((device, live)) = out.assess.as_mut() {
            for alert in live.frame(&f) {
                let mut buf = Vec::new();
                status_message(
                    &mut buf,
                    *device,
                    codec::s_to_timestamp(now),
                    &assess_status(&alert),
                );
                // No peer yet: nobody to tell.
                let _ = out.tie_statuses.send(Arc::new(buf));
            }
        }
        if let (Some(device), Some(ties)) = (out.ties_device, &f.ties) {
            for notice in notices.of(ties) {
                let status = tie_status(&notice, &registration);
                let mut buf = Vec::new();
                status_message(&mut buf, device, codec::s_to_timestamp(now), &status);
                // No peer yet: nobody to tell.
                let _ = out.tie_statuses.send(Arc::new(buf));
            }
        }
        if f.positions_m.is_empty() {
            continue;
        }
        let mut points = Vec::with_capacity(f.positions_m.len());
        for p in f.positions_m.chunks_exact(3) {
            let s = registration.point_to_sender([p[0] as f64, p[1] as f64, p[2] as f64]);
            points.extend(s.map(|x| x as f32));
        }
        tx.send_replace(Some(Arc::new(SurfaceFrame {
            frame: f.frame,
            points,
        })));
    }
}

/// The STATUS of an assessment alert: `ASSESS_WARN` (code OK, subcode 1)
/// or `ASSESS_FAIL` (an error, subcode 2), the alert's line as text.
pub fn assess_status(a: &crate::client::report::assess::Alert) -> StatusMsg {
    use fissure_shared::assessment::Grade;
    let (code, subcode, name) = match a.grade {
        Grade::Fail => (status_code::UNKNOWN_ERROR, 2, "ASSESS_FAIL"),
        _ => (status_code::OK, 1, "ASSESS_WARN"),
    };
    StatusMsg {
        code,
        subcode,
        error_name: name.to_owned(),
        message: a.line(),
    }
}

/// The STATUS of a tie cut or torn, its place in the sender's frame and
/// units: `TIE_CUT`, `TIE_TORN`, `VESSEL_TORN` (an error: an injury) or
/// `TIE_RELEASED` (its event was in a frame the bridge did not receive).
pub fn tie_status(n: &TieNotice, registration: &Registration) -> StatusMsg {
    let kind = n.kind_name();
    let (code, name, text) = match n.how {
        TieHow::Released => (
            status_code::OK,
            "TIE_RELEASED",
            format!(
                "tie {} released (cut or torn in a frame this bridge did not receive)",
                n.tie
            ),
        ),
        how => {
            let at = registration.point_to_sender(n.position_m);
            let (code, name, verb) = match how {
                TieHow::Cut => (status_code::OK, "TIE_CUT", "cut by"),
                _ if n.is_injury() => (status_code::UNKNOWN_ERROR, "VESSEL_TORN", "torn, nearest"),
                _ => (status_code::OK, "TIE_TORN", "torn, nearest"),
            };
            (
                code,
                name,
                format!(
                    "{kind} {} {verb} {} at t = {:.3} s, at ({:.2}, {:.2}, {:.2}) (sender units), strain {:.3}",
                    n.tie, n.instrument, n.sim_time_s, at[0], at[1], at[2], n.strain
                ),
            )
        }
    };
    StatusMsg {
        code,
        subcode: i64::from(n.tie),
        error_name: name.to_owned(),
        message: text,
    }
}

async fn accept_loop(
    listener: TcpListener,
    shared: Arc<Shared>,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) {
    let mut conns = tokio::task::JoinSet::new();
    loop {
        let (stream, from) = tokio::select! {
            r = listener.accept() => match r {
                Ok(x) => x,
                Err(e) => {
                    tracing::warn!("OpenIGTLink accept: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = stopped.changed() => break,
            // Reap ended connections as they go.
            Some(_) = conns.join_next(), if !conns.is_empty() => continue,
        };
        tracing::info!("OpenIGTLink peer {from} connected");
        conns.spawn(serve_peer(stream, from, shared.clone(), stopped.clone()));
    }
    while conns.join_next().await.is_some() {}
}

async fn connect_loop(
    to: String,
    shared: Arc<Shared>,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) {
    let mut failing = false;
    loop {
        let conn = tokio::select! {
            c = TcpStream::connect(&to) => c,
            _ = stopped.changed() => return,
        };
        match conn {
            Ok(stream) => {
                failing = false;
                let from = stream
                    .peer_addr()
                    .unwrap_or_else(|_| ([0, 0, 0, 0], 0).into());
                tracing::info!("OpenIGTLink: connected to {to} ({from})");
                serve_peer(stream, from, shared.clone(), stopped.clone()).await;
                if *stopped.borrow() {
                    return;
                }
                tracing::warn!("OpenIGTLink: {to} closed the connection; reconnecting");
            }
            Err(e) => {
                if !failing {
                    tracing::warn!(
                        "OpenIGTLink: cannot connect to {to}: {e}; retrying every second"
                    );
                }
                failing = true;
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_secs(1)) => {}
            _ = stopped.changed() => return,
        }
    }
}

/// Serves one peer until it leaves, its framing is lost or the bridge stops.
async fn serve_peer(
    stream: TcpStream,
    from: SocketAddr,
    shared: Arc<Shared>,
    mut stopped: tokio::sync::watch::Receiver<bool>,
) {
    // Answers are small and latency-bound.
    let _ = stream.set_nodelay(true);
    shared.counters.connections.fetch_add(1, Ordering::Relaxed);
    let id = shared.next_peer.fetch_add(1, Ordering::Relaxed);
    let (tx, rx) = tokio::sync::mpsc::channel::<Vec<u8>>(PEER_QUEUE);
    shared
        .peers
        .lock()
        .expect("peers lock")
        .insert(id, tx.clone());
    let (read, write) = stream.into_split();
    let writer = tokio::spawn(write_loop(write, rx, shared.clone(), from));
    let end = tokio::select! {
        r = read_loop(read, id, from, &shared, &tx) => r,
        _ = stopped.changed() => Ok(()),
    };
    if let Err(e) = end {
        tracing::warn!("OpenIGTLink peer {from}: {e:#}");
    }
    shared.peers.lock().expect("peers lock").remove(&id);
    drop(tx);
    writer.abort();
    let _ = writer.await;
    tracing::info!("OpenIGTLink peer {from} left");
}

async fn read_loop(
    read: tokio::net::tcp::OwnedReadHalf,
    peer: u64,
    from: SocketAddr,
    shared: &Shared,
    tx: &PeerTx,
) -> anyhow::Result<()> {
    let counters = &shared.counters;
    let mut r = BufReader::with_capacity(64 << 10, read);
    let mut head = [0u8; HEADER_LEN];
    let mut body = Vec::with_capacity(1024);
    let mut unknown_devices = HashSet::new();
    let mut ignored_types = HashSet::new();
    loop {
        match r.read_exact(&mut head).await {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(e).context("reading a header"),
        }
        counters.received.fetch_add(1, Ordering::Relaxed);
        let h = match codec::parse_header(&head) {
            Ok(h) => h,
            Err(e) => {
                counters.bad(from, &e);
                bail!("closing the connection: its message framing is lost ({e})");
            }
        };
        body.resize(h.body_size as usize, 0);
        r.read_exact(&mut body).await.context("reading a body")?;
        let kind = h.type_str();
        if kind != "TRANSFORM" && kind != "POSITION" {
            counters.ignored.fetch_add(1, Ordering::Relaxed);
            if ignored_types.len() < 64 && ignored_types.insert(kind.to_owned()) {
                tracing::info!(
                    "OpenIGTLink peer {from}: {kind} messages are not read by the bridge"
                );
            }
            continue;
        }
        let parsed = codec::content(&h, &body).and_then(|c| codec::parse_content(kind, c));
        let (position, q) = match parsed {
            Ok(Body::Transform(t)) => {
                let m = Matrix3::from_fn(|r, c| t.rotation[r][c] as f64);
                (t.translation.map(|x| x as f64), rotation_quaternion(&m))
            }
            Ok(Body::Position(p)) => {
                let [x, y, z, w] = p.quaternion.map(|x| x as f64);
                let q = nalgebra::Quaternion::new(w, x, y, z);
                if q.norm() < 1e-6 {
                    counters.bad(
                        from,
                        &IgtlError::NotFinite {
                            kind: "POSITION",
                            field: "the quaternion (zero)",
                        },
                    );
                    continue;
                }
                (
                    p.position.map(|x| x as f64),
                    UnitQuaternion::from_quaternion(q),
                )
            }
            Ok(_) => continue,
            Err(e) => {
                counters.bad(from, &e);
                continue;
            }
        };
        let device = h.device();
        let Some(&lane) = shared.map.get(device) else {
            counters.not_forwarded.fetch_add(1, Ordering::Relaxed);
            if unknown_devices.len() < 64 && unknown_devices.insert(device.to_owned()) {
                tracing::warn!(
                    "OpenIGTLink peer {from}: device {device:?} maps to no bridged instrument (--igtl-map DEVICE=INSTRUMENT)"
                );
                send_status(
                    shared,
                    tx,
                    &h,
                    status_code::NOT_FOUND,
                    "UNKNOWN_DEVICE",
                    &format!("device {device:?} maps to no bridged instrument"),
                );
            }
            continue;
        };
        let p = shared.registration.position_m(position);
        let q = shared.registration.orientation(&q);
        let to = Pending {
            peer,
            device: h.device_name,
            timestamp: h.timestamp,
        };
        // Time, sequence and forwarding under one lock: poses of one lane
        // from two peers reach the stream in sequence order.
        let forwarded = {
            let mut clock = shared.clocks[lane].lock().expect("clock lock");
            let (t_s, seq) = clock.next(h.timestamp_s());
            let pose = pb::PoseSample::new(t_s, seq, p, [q.w, q.i, q.j, q.k]);
            shared.lanes.forward(lane, pose, to)
        };
        if forwarded {
            counters.forwarded.fetch_add(1, Ordering::Relaxed);
        } else {
            counters.not_forwarded.fetch_add(1, Ordering::Relaxed);
            send_status(
                shared,
                tx,
                &h,
                status_code::BUSY,
                "LANE_FULL",
                &format!(
                    "instrument {:?}: its stream is full or closed",
                    shared.lanes.name(lane)
                ),
            );
        }
    }
}

fn send_status(shared: &Shared, tx: &PeerTx, h: &codec::Header, code: u16, name: &str, text: &str) {
    let mut out = Vec::new();
    status_message(
        &mut out,
        h.device_name,
        h.timestamp,
        &StatusMsg {
            code,
            subcode: 0,
            error_name: name.to_owned(),
            message: text.to_owned(),
        },
    );
    if tx.try_send(out).is_ok() {
        shared.counters.statuses.fetch_add(1, Ordering::Relaxed);
    } else {
        shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
    }
}

/// Writes a peer's answers as they come and, between them, the newest
/// surface frame it has not had.
async fn write_loop(
    mut w: tokio::net::tcp::OwnedWriteHalf,
    mut answers: tokio::sync::mpsc::Receiver<Vec<u8>>,
    shared: Arc<Shared>,
    from: SocketAddr,
) {
    let mut surface = shared.surface.clone();
    let mut surface_open = shared.surface_device.is_some();
    let mut ties = shared.tie_statuses.subscribe();
    let mut ties_open = true;
    let mut sent_topology = false;
    let mut buf = Vec::new();
    // A frame published before the peer came is sent at once.
    surface.mark_changed();
    loop {
        let r = tokio::select! {
            biased;
            m = answers.recv() => match m {
                Some(b) => w.write_all(&b).await,
                None => return,
            },
            t = ties.recv(), if ties_open => match t {
                Ok(b) => {
                    let r = w.write_all(&b).await;
                    if r.is_ok() {
                        shared.counters.statuses.fetch_add(1, Ordering::Relaxed);
                    }
                    r
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!("OpenIGTLink peer {from}: {n} tie messages dropped (the peer reads too slowly)");
                    continue;
                }
                Err(tokio::sync::broadcast::error::RecvError::Closed) => {
                    ties_open = false;
                    continue;
                }
            },
            c = surface.changed(), if surface_open => {
                if c.is_err() {
                    surface_open = false;
                    continue;
                }
                let Some(frame) = surface.borrow_and_update().clone() else { continue };
                let Some(device) = shared.surface_device else { continue };
                let with_topology = shared.topology_every || !sent_topology;
                let empty = Cells::default();
                let polys = if with_topology { &*shared.topology } else { &empty };
                let now = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0.0, |d| d.as_secs_f64());
                write_message(&mut buf, type_field("POLYDATA"), device, codec::s_to_timestamp(now), |o| {
                    codec::polydata_content(&frame.points, polys, &empty, o)
                });
                let r = w.write_all(&buf).await;
                if r.is_ok() {
                    sent_topology = true;
                    shared.counters.polydata_sent.fetch_add(1, Ordering::Relaxed);
                }
                r
            }
        };
        if let Err(e) = r {
            tracing::warn!("OpenIGTLink peer {from}: writing: {e}");
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registration_maps_millimetres_into_the_scene_and_back() {
        // A quarter turn about z and a shift of (10, 20, 30) mm.
        let r = Registration::parse("0 -1 0 10, 0 1e-300 0 0, 0 0 1 30, 0 0 0 1", 0.001);
        assert!(
            matches!(r, Err(RegistrationError::NotRotation(..))),
            "{r:?}"
        );
        let r = Registration::parse("0 -1 0 10  1 0 0 20  0 0 1 30  0 0 0 1", 0.001).unwrap();
        let p = r.position_m([1.0, 2.0, 3.0]);
        let want = [0.008, 0.021, 0.033];
        for k in 0..3 {
            assert!((p[k] - want[k]).abs() < 1e-12, "{p:?}");
        }
        let back = r.point_to_sender(p);
        for k in 0..3 {
            assert!((back[k] - [1.0, 2.0, 3.0][k]).abs() < 1e-9, "{back:?}");
        }
        // A force along scene +x is along sender -y.
        let f = r.vector_to_sender([1.0, 0.0, 0.0]);
        assert!((f[1] + 1.0).abs() < 1e-12 && f[0].abs() < 1e-12, "{f:?}");
        // Orientations compose: identity in the sender is the registration's rotation.
        let q = r.orientation(&UnitQuaternion::identity());
        assert!((q.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn bad_registrations_are_refused_with_their_cause() {
        assert_eq!(
            Registration::parse("1 0 0", 0.001),
            Err(RegistrationError::Count(3))
        );
        assert_eq!(
            Registration::parse("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 x", 0.001),
            Err(RegistrationError::Number("x".into()))
        );
        assert_eq!(
            Registration::parse("1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1", 0.001),
            Err(RegistrationError::LastRow)
        );
        // A mirror has det -1.
        assert!(matches!(
            Registration::parse("-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", 0.001),
            Err(RegistrationError::NotRotation(..))
        ));
        for u in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Registration::parse("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", u),
                Err(RegistrationError::Unit(_))
            ));
        }
    }

    #[test]
    fn tracker_matrices_give_their_quaternion() {
        // A rotation of 0.7 rad about (1, 2, 2)/3, rounded to f32 as a
        // TRANSFORM carries it.
        let axis = nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 2.0));
        let q = UnitQuaternion::from_axis_angle(&axis, 0.7);
        let m = q.to_rotation_matrix().into_inner().map(|x| x as f32 as f64);
        let got = rotation_quaternion(&m);
        assert!(got.angle_to(&q) < 1e-6, "{got:?} {q:?}");
        assert!((got.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn lane_clocks_start_at_zero_and_number_the_poses() {
        let mut c = LaneClock::default();
        assert_eq!(c.next(1_700_000_000.5), (0.0, 1));
        let (t, s) = c.next(1_700_000_000.75);
        assert_eq!((t, s), (0.25, 2));
        // A small step back goes through (the server rejects it).
        assert_eq!(c.next(1_700_000_000.5).0, 0.0);
        // A restarted sender: time carries on from the last pose.
        assert_eq!(c.next(1_000.0).0, 0.25);
        assert_eq!(c.next(1_000.5).0, 0.75);
        // A sender without timestamps: time since its first pose.
        let mut c = LaneClock::default();
        let (t0, _) = c.next(0.0);
        std::thread::sleep(Duration::from_millis(5));
        let (t1, s1) = c.next(0.0);
        assert!(t0 < 1e-3 && t1 >= 0.005 && s1 == 2, "{t0} {t1}");
    }

    /// The proto's `SafetyFlag` is the one source of the flags: every bit
    /// it defines is named here by its proto name, and no other bit is.
    #[test]
    fn safety_flag_names_are_the_proto_enum_names() {
        for bit in 0..32 {
            let v = 1u32 << bit;
            match pb::SafetyFlag::try_from(v as i32) {
                Ok(f) => assert_eq!(
                    flag_names(v),
                    f.as_str_name().trim_start_matches("SAFETY_FLAG_"),
                    "bit {bit}"
                ),
                Err(_) => assert_eq!(flag_names(v), format!("{v:#x}"), "bit {bit}"),
            }
        }
    }

    /// The engine's flags are the proto's, bit for bit.
    #[cfg(feature = "lab")]
    #[test]
    fn the_engines_safety_flags_are_the_proto_flags() {
        use fissure_engine::sim::flags;
        let pairs = [
            (
                flags::FORCE_ABOVE_THRESHOLD,
                pb::SafetyFlag::ForceAboveThreshold,
            ),
            (flags::FORCE_CLAMPED, pb::SafetyFlag::ForceClamped),
            (flags::MODEL_STALE, pb::SafetyFlag::ModelStale),
            (flags::SOLVER_FAILED, pb::SafetyFlag::SolverFailed),
            (flags::POSE_JUMP, pb::SafetyFlag::PoseJump),
            (flags::COLUMNS_PENDING, pb::SafetyFlag::ColumnsPending),
            (flags::CONTACT_UNSOLVED, pb::SafetyFlag::ContactUnsolved),
            (flags::VESSEL_TORN, pb::SafetyFlag::VesselTorn),
        ];
        for (engine, proto) in pairs {
            assert_eq!(engine, proto as u32, "{}", proto.as_str_name());
        }
        // Every proto flag has its engine constant above.
        let named = (0..32)
            .filter(|b| pb::SafetyFlag::try_from(1i32 << b).is_ok())
            .count();
        assert_eq!(named, pairs.len());
    }

    /// Each tie notice becomes one STATUS: a torn vessel an error, its
    /// place in the sender's units, a tie released unseen named so.
    #[test]
    fn tie_notices_become_status_messages() {
        let notice = |how: TieHow, kind: pb::TieKind| TieNotice {
            tie: 4,
            kind: Some(kind),
            how,
            instrument: "blade".into(),
            sim_time_s: 1.25,
            position_m: [0.01, -0.02, 0.003],
            strain: 0.125,
        };
        let r = Registration::default();
        let cut = tie_status(&notice(TieHow::Cut, pb::TieKind::Trabecula), &r);
        assert_eq!((cut.code, cut.subcode), (status_code::OK, 4));
        assert_eq!(cut.error_name, "TIE_CUT");
        assert_eq!(
            cut.message,
            "trabecula 4 cut by blade at t = 1.250 s, at (10.00, -20.00, 3.00) (sender units), strain 0.125"
        );
        let torn = tie_status(&notice(TieHow::Torn, pb::TieKind::Trabecula), &r);
        assert_eq!(
            (torn.code, torn.error_name.as_str()),
            (status_code::OK, "TIE_TORN")
        );
        let vessel = tie_status(&notice(TieHow::Torn, pb::TieKind::Vessel), &r);
        assert_eq!(vessel.code, status_code::UNKNOWN_ERROR);
        assert_eq!(vessel.error_name, "VESSEL_TORN");
        assert!(vessel.message.starts_with("vessel 4 torn, nearest blade"));
        let mut unseen = notice(TieHow::Released, pb::TieKind::Trabecula);
        unseen.kind = None;
        assert_eq!(tie_status(&unseen, &r).error_name, "TIE_RELEASED");
    }

    #[test]
    fn safety_flags_are_named() {
        assert_eq!(flag_names(0), "none");
        assert_eq!(flag_names(1 | 4), "FORCE_ABOVE_THRESHOLD|MODEL_STALE");
        assert_eq!(flag_names(64 | 256), "CONTACT_UNSOLVED|0x100");
        assert_eq!(flag_names(128), "VESSEL_TORN");
    }

    #[test]
    fn device_maps_are_checked() {
        let m = parse_map(&["Tracker=left".into(), "StylusToReference=right".into()]).unwrap();
        assert_eq!(m["Tracker"], "left");
        assert!(parse_map(&["Tracker".into()]).is_err());
        assert!(parse_map(&["A=left".into(), "A=right".into()]).is_err());
        assert!(parse_map(&["ThisDeviceNameIsTooLongForIGTL=left".into()]).is_err());
    }
}
