//! fissure-server: the tonic adapter of `fissure.v1` over `fissure-engine`;
//! it moves messages and holds no logic (the engine never imports it).
//!
//! The service answers `UNAVAILABLE` until the scene is loaded and factorized;
//! health reports `NOT_SERVING` until then, for the server as a whole (`""`,
//! what probes ask by default) and for `fissure.v1.Fissure`. With a token
//! ([`ServeOptions::token`]), the calls that change the simulation (`Haptic`,
//! `Reset`) need it; the calls that only read (`GetScene`, `GetSurface`,
//! `Watch`, `GetStats`), health and reflection are open. Each haptic stream gets its own
//! OS thread for its force loop ([`fissure_engine::sim::runtime::haptic_stream`], with its pose
//! budget and the session's recording; this module converts messages and
//! forwards them): a 1 kHz loop should not share a scheduler
//! with watchers' serialisation work. The stream itself is read by a task on
//! the runtime, which hands decoded poses to the force loop through a
//! channel: the force loop's thread never polls the HTTP/2 connection itself
//! (when it did, a pose now and then waited for the next one to arrive
//! before it was read, about a millisecond at 1 kHz). Serve from a
//! [`Transport`] for real-time transport threads.
//!
//! Shutdown ([`RunningServer::shutdown`]) ends every open stream first (haptic
//! and watch streams end with `UNAVAILABLE`, "the server is shutting down"),
//! so that the graceful HTTP/2 shutdown does not wait on clients that keep
//! their streams open; connections still open after [`SHUTDOWN_GRACE`] are
//! dropped.
//!
//! A haptic client that stops reading its force samples is not served
//! forever into a growing queue: once [`MAX_UNREAD_ANSWERS`] answers wait
//! unread, the stream's force loop waits for the client to take one (its
//! poses meanwhile wait in HTTP/2 flow control: a client reading slower
//! than it sends is paced, not dropped), and when the queue has stayed full
//! for [`UNREAD_GRACE`] its stream ends with `RESOURCE_EXHAUSTED` (after
//! the answers already queued) and the instrument is released; the server
//! logs it. Its
//! connection and the other streams on it keep working: while the force
//! loop waits, the stream's pose reader stops once its channel is full, and
//! each stream's receive window is [`STREAM_RECEIVE_WINDOW_BYTES`], so that
//! the poses held in the HTTP/2 layer stay within its limits (with the default 1 MiB window, about 3,000
//! unread 100-byte poses made hyper's HTTP/2 layer end the whole connection
//! with GOAWAY `ENHANCE_YOUR_CALM`, "too_many_data_frames").

pub mod convert;
pub mod monitor;
pub mod recording;
pub mod reflection;
pub mod transport;

pub use transport::Transport;

use fissure_engine::sim::core::pose::{PoseError, RawPose};
use fissure_engine::sim::runtime::haptic_stream::{self, Rejection};
use fissure_engine::sim::{ClaimError, ForceOut, Simulation};
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_server::{Fissure, FissureServer};
use fissure_proto::{AUTHORIZATION_METADATA_KEY, INSTRUMENT_METADATA_KEY};
use futures::{Stream, StreamExt};
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, OnceLock};
use std::time::Duration;
use tokio_stream::wrappers::{ReceiverStream, WatchStream};
use tonic::metadata::MetadataMap;
use tonic::{Request, Response, Status, Streaming};
use tonic_health::ServingStatus;

/// Largest message accepted from a client, bytes (poses are ~100 bytes).
pub const MAX_DECODING_MESSAGE_BYTES: usize = 64 * 1024;

/// Largest message sent, bytes (a frame of a 16k-vertex surface is ~200 kB).
pub const MAX_ENCODING_MESSAGE_BYTES: usize = 16 * 1024 * 1024;

/// Answers (force samples and rejections) a haptic client may leave unread
/// in the server's queue before its stream is ended with
/// `RESOURCE_EXHAUSTED`: about a second at 1 kHz, beyond what its own HTTP/2
/// window and the transport's buffers hold (with a 64 KiB window, about
/// 1,500 answers of 90 bytes: at 1 kHz the queue is full after about
/// 2.5 s of not reading, and the stream ends [`UNREAD_GRACE`] later). A client that pipelines its poses has a round trip's
/// worth unread at any time (tens at 1 kHz), far below it.
pub const MAX_UNREAD_ANSWERS: usize = 1024;

/// How long a haptic stream's full answer queue may stay full before its
/// client is taken to have stopped reading. A flooding client (10 kHz)
/// fills the queue in a tenth of a second: one whose reader is merely held
/// up for that long on a loaded machine must not lose its stream.
pub const UNREAD_GRACE: Duration = Duration::from_millis(500);

/// HTTP/2 receive window of each stream, bytes: the poses a stream's reader
/// has not taken yet that the HTTP/2 layer holds (about 700 poses). hyper's
/// default (1 MiB) let small pose frames exhaust its per-connection budget
/// for framing overhead (half the connection window) before flow control
/// pushed back, and it then closed the connection.
pub const STREAM_RECEIVE_WINDOW_BYTES: u32 = 64 * 1024;

/// Longest wait, after the streams are ended, for connections to close at
/// shutdown before they are dropped.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

pub use fissure_engine::sim::runtime::budget::{MAX_POSE_RATE_FACTOR, POSE_BURST_S};

/// How clients must authenticate and where the server listens.
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// Bearer token required by the calls that change the simulation
    /// (`Haptic`, `Reset`), if any.
    pub token: Option<String>,
    /// TLS identity (PEM certificate chain and key), if TLS is on.
    pub tls: Option<(Vec<u8>, Vec<u8>)>,
}

/// The `fissure.v1.Fissure` service over a (possibly still loading) simulation.
#[derive(Debug, Clone)]
pub struct FissureService {
    sim: Arc<OnceLock<Arc<Simulation>>>,
    token: Option<Arc<str>>,
    /// Becomes true when the server shuts down; open streams end then.
    stopping: tokio::sync::watch::Sender<bool>,
}

fn shutting_down() -> Status {
    Status::unavailable("the server is shutting down")
}

impl FissureService {
    /// A service whose simulation is set later with [`FissureService::set_simulation`].
    pub fn new(token: Option<String>) -> Self {
        Self {
            sim: Arc::new(OnceLock::new()),
            token: token.map(Into::into),
            stopping: tokio::sync::watch::Sender::new(false),
        }
    }

    /// Ends every open haptic and watch stream (with `UNAVAILABLE`) and makes
    /// new ones fail the same way.
    pub fn stop_streams(&self) {
        self.stopping.send_replace(true);
    }

    /// Makes the loaded simulation available to clients.
    pub fn set_simulation(&self, sim: Arc<Simulation>) {
        let _ = self.sim.set(sim);
    }

    fn sim(&self) -> Result<&Arc<Simulation>, Status> {
        self.sim
            .get()
            .ok_or_else(|| Status::unavailable("the scene is still loading"))
    }

    /// Checks the bearer token of a call that changes the simulation
    /// (`call` names it in the error). The scheme is case-insensitive
    /// (RFC 7235), one or more spaces separate it from the token; exactly
    /// one `authorization` value is accepted.
    fn check_token(&self, metadata: &MetadataMap, call: &str) -> Result<(), Status> {
        let Some(token) = &self.token else {
            return Ok(());
        };
        let values: Vec<_> = metadata
            .get_all(AUTHORIZATION_METADATA_KEY)
            .iter()
            .collect();
        let value = match values.as_slice() {
            [] => {
                return Err(Status::unauthenticated(format!(
                    "this server requires `authorization: Bearer <token>` for {call} \
                     (the calls that change the simulation: Haptic, Reset)"
                )));
            }
            [one] => *one,
            many => {
                return Err(Status::unauthenticated(format!(
                    "{} `authorization` values given; send exactly one `Bearer <token>`",
                    many.len()
                )));
            }
        };
        let given = value
            .to_str()
            .ok()
            .and_then(|v| v.split_once(' '))
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, t)| t.trim_start_matches(' '));
        match given {
            Some(g) if constant_time_eq(g.as_bytes(), token.as_bytes()) => Ok(()),
            Some(_) => Err(Status::unauthenticated("the bearer token is wrong")),
            None => Err(Status::unauthenticated(
                "the `authorization` value is not `Bearer <token>`",
            )),
        }
    }
}

/// The instrument a haptic stream claims: the single `fissure-instrument`
/// value.
fn instrument_name(metadata: &MetadataMap) -> Result<String, Status> {
    let values: Vec<_> = metadata.get_all(INSTRUMENT_METADATA_KEY).iter().collect();
    let value = match values.as_slice() {
        [] => {
            return Err(Status::invalid_argument(format!(
                "the `{INSTRUMENT_METADATA_KEY}` metadata naming the instrument is missing"
            )));
        }
        [one] => *one,
        many => {
            let names: Vec<String> = many
                .iter()
                .map(|v| format!("{:?}", v.to_str().unwrap_or("(not ASCII)")))
                .collect();
            return Err(Status::invalid_argument(format!(
                "{} `{INSTRUMENT_METADATA_KEY}` values given ({}); a stream claims exactly one instrument",
                many.len(),
                names.join(", ")
            )));
        }
    };
    value
        .to_str()
        .map(str::to_owned)
        .map_err(|_| Status::invalid_argument(format!("`{INSTRUMENT_METADATA_KEY}` is not ASCII")))
}

/// Queues one answer of a haptic stream (on the stream's force-loop
/// thread, which waits while the queue is full); false when the stream is
/// over: the client went away, or it left [`MAX_UNREAD_ANSWERS`] answers
/// unread for [`UNREAD_GRACE`] (then the last slot of the queue, kept for
/// it, carries the status saying so).
fn answer(
    tx: &tokio::sync::mpsc::Sender<Result<pb::ForceSample, Status>>,
    reply: pb::ForceSample,
    instrument: &str,
) -> bool {
    let full_since = std::time::Instant::now();
    loop {
        if tx.is_closed() {
            return false;
        }
        if tx.capacity() > 1 {
            return tx.try_send(Ok(reply)).is_ok();
        }
        if full_since.elapsed() >= UNREAD_GRACE {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    tracing::warn!(
        %instrument,
        unread = MAX_UNREAD_ANSWERS,
        "a haptic client stopped reading its force samples: its stream is ended \
         (RESOURCE_EXHAUSTED) and the instrument released"
    );
    let _ = tx.try_send(Err(Status::resource_exhausted(format!(
        "force samples not read: the client stopped reading its stream ({MAX_UNREAD_ANSWERS} \
         answers queued beyond what its HTTP/2 window holds), so the stream is ended and \
         instrument {instrument:?} released; read the answers as they come (one per pose)"
    ))));
    false
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

#[tonic::async_trait]
impl Fissure for FissureService {
    async fn get_scene(
        &self,
        _: Request<pb::GetSceneRequest>,
    ) -> Result<Response<pb::SceneDescription>, Status> {
        let sim = self.sim()?;
        Ok(Response::new(convert::scene_description(
            sim.scene(),
            sim.model(),
        )))
    }

    async fn get_surface(
        &self,
        _: Request<pb::GetSurfaceRequest>,
    ) -> Result<Response<pb::SurfaceMesh>, Status> {
        Ok(Response::new(convert::surface(self.sim()?.model())))
    }

    async fn reset(
        &self,
        req: Request<pb::ResetRequest>,
    ) -> Result<Response<pb::ResetResponse>, Status> {
        let sim = self.sim()?;
        self.check_token(req.metadata(), "Reset")?;
        tracing::info!(remote = ?req.remote_addr(), "reset: the tissue returns to rest");
        Ok(Response::new(pb::ResetResponse { frame: sim.reset() }))
    }

    type HapticStream = BoxStream<pb::ForceSample>;

    async fn haptic(
        &self,
        req: Request<Streaming<pb::PoseSample>>,
    ) -> Result<Response<Self::HapticStream>, Status> {
        let sim = self.sim()?.clone();
        self.check_token(req.metadata(), "Haptic")?;
        if *self.stopping.borrow() {
            return Err(shutting_down());
        }
        let name = instrument_name(req.metadata())?;
        let claim = sim.claim(&name).map_err(|e| match e {
            ClaimError::Unknown { .. } => Status::not_found(e.to_string()),
            ClaimError::Taken(_) => Status::already_exists(e.to_string()),
            ClaimError::ShuttingDown => Status::unavailable(e.to_string()),
        })?;
        let mut inbound = req.into_inner();
        // One slot more than the unread answers allowed: the last carries the
        // status that ends the stream (see `answer`).
        let (tx, rx) =
            tokio::sync::mpsc::channel::<Result<pb::ForceSample, Status>>(MAX_UNREAD_ANSWERS + 1);
        let mut stopping = self.stopping.subscribe();
        let stopped = self.stopping.subscribe();
        // The stream is read on the runtime, by a task of its own: the force
        // loop's thread only takes decoded poses from a channel.
        let (pose_tx, poses) = tokio::sync::mpsc::channel::<Inbound>(64);
        tokio::spawn(async move {
            loop {
                let next = tokio::select! {
                    m = inbound.message() => match m {
                        Ok(Some(m)) => Inbound::Pose(m),
                        Ok(None) => Inbound::End,
                        Err(status) => Inbound::Failed(status),
                    },
                    _ = stopping.wait_for(|s| *s) => Inbound::Stopping,
                };
                let last = !matches!(next, Inbound::Pose(_));
                if pose_tx.send(next).await.is_err() || last {
                    break;
                }
            }
        });
        let port = StreamPort {
            instrument: name,
            poses,
            stopped,
            tx,
        };
        haptic_stream::spawn(claim, port)
            .map_err(|e| Status::internal(format!("cannot start the force loop: {e}")))?;
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    type WatchStream = BoxStream<pb::DeformationFrame>;

    async fn watch(
        &self,
        req: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchStream>, Status> {
        let sim = self.sim()?;
        if *self.stopping.borrow() {
            return Err(shutting_down());
        }
        let include = req.get_ref().include_positions;
        let guard = sim.watch().ok_or_else(|| {
            let max = sim.max_watchers();
            Status::resource_exhausted(format!(
                "the server's watcher limit is reached: {max} watchers are connected, \
                 at most {max} (`fissure-server --max-watchers`)"
            ))
        })?;
        let rx = guard.rx.clone();
        let mut stopping = self.stopping.subscribe();
        let stream = WatchStream::new(rx)
            .map(move |frame| {
                let _keep = &guard;
                Ok(convert::frame(&frame, include, include))
            })
            .take_until(async move {
                let _ = stopping.wait_for(|s| *s).await;
            })
            .chain(futures::stream::once(async { Err(shutting_down()) }));
        Ok(Response::new(Box::pin(stream)))
    }

    async fn get_stats(
        &self,
        _: Request<pb::GetStatsRequest>,
    ) -> Result<Response<pb::Stats>, Status> {
        Ok(Response::new(convert::stats(&self.sim()?.stats())))
    }
}

/// A running server: its address, health reporter and shutdown switch.
#[derive(Debug)]
pub struct RunningServer {
    /// The address it listens on.
    pub addr: SocketAddr,
    /// The service (to set the simulation once loaded).
    pub service: FissureService,
    health: tonic_health::server::HealthReporter,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
}

impl RunningServer {
    /// Makes the simulation available and reports SERVING (for `""` and
    /// `fissure.v1.Fissure`); starts the watch on the deformation loop's pace
    /// ([`monitor`]).
    pub async fn set_simulation(&self, sim: Arc<Simulation>) {
        self.service.set_simulation(sim.clone());
        set_health(&self.health, ServingStatus::Serving).await;
        tokio::spawn(monitor::watch_pace(sim, self.service.stopping.subscribe()));
    }

    /// Ends the open streams, stops accepting calls and waits (at most
    /// [`SHUTDOWN_GRACE`]) for the connections to close; then drops them.
    /// Health reports NOT_SERVING from the start of it.
    pub async fn shutdown(mut self) -> anyhow::Result<()> {
        set_health(&self.health, ServingStatus::NotServing).await;
        self.service.stop_streams();
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        match tokio::time::timeout(SHUTDOWN_GRACE, &mut self.task).await {
            Ok(joined) => joined??,
            Err(_) => {
                tracing::warn!(
                    "connections still open {} s after shutdown; dropping them",
                    SHUTDOWN_GRACE.as_secs()
                );
                self.task.abort();
            }
        }
        Ok(())
    }
}

/// The service names health answers for: the server as a whole (`""`, what
/// probes ask when they name no service) and `fissure.v1.Fissure`.
pub const HEALTH_SERVICES: [&str; 2] = ["", "fissure.v1.Fissure"];

async fn set_health(health: &tonic_health::server::HealthReporter, status: ServingStatus) {
    for name in HEALTH_SERVICES {
        health.set_service_status(name, status).await;
    }
}

/// Binds `addr` and serves `fissure.v1`, health and reflection (`v1` and
/// `v1alpha`). Health says NOT_SERVING, for `""` and `fissure.v1.Fissure`,
/// until [`RunningServer::set_simulation`].
pub async fn serve(addr: SocketAddr, options: ServeOptions) -> anyhow::Result<RunningServer> {
    use anyhow::Context;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let addr = listener.local_addr()?;
    let (health, health_service) = tonic_health::server::health_reporter();
    set_health(&health, ServingStatus::NotServing).await;
    let reflection = reflection::Reflection::new(&[
        fissure_proto::FILE_DESCRIPTOR_SET,
        tonic_health::pb::FILE_DESCRIPTOR_SET,
    ])
    .context("building the reflection service")?;
    let service = FissureService::new(options.token.clone());
    let grpc = FissureServer::new(service.clone())
        .max_decoding_message_size(MAX_DECODING_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_ENCODING_MESSAGE_BYTES);
    let mut builder = tonic::transport::Server::builder()
        .tcp_nodelay(true)
        .initial_stream_window_size(STREAM_RECEIVE_WINDOW_BYTES);
    if let Some((cert, key)) = &options.tls {
        builder = builder
            .tls_config(
                tonic::transport::ServerTlsConfig::new()
                    .identity(tonic::transport::Identity::from_pem(cert, key)),
            )
            .context("configuring TLS")?;
    }
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let router = builder
        .add_service(health_service)
        .add_service(reflection.v1())
        .add_service(reflection.v1alpha())
        .add_service(grpc);
    let incoming = tokio_stream::wrappers::TcpListenerStream::new(listener).map(|s| {
        if let Ok(s) = &s {
            let _ = s.set_nodelay(true);
        }
        s
    });
    let task = tokio::spawn(router.serve_with_incoming_shutdown(incoming, async move {
        let _ = rx.await;
    }));
    Ok(RunningServer {
        addr,
        service,
        health,
        shutdown: Some(tx),
        task,
    })
}

/// What the reader of a haptic stream hands its force loop.
type Inbound = haptic_stream::Inbound<pb::PoseSample, Status>;

/// The service's end of a haptic stream: decoded poses in, force samples out.
struct StreamPort {
    instrument: String,
    poses: tokio::sync::mpsc::Receiver<Inbound>,
    /// Becomes true when the server shuts down.
    stopped: tokio::sync::watch::Receiver<bool>,
    tx: tokio::sync::mpsc::Sender<Result<pb::ForceSample, Status>>,
}

impl haptic_stream::HapticPort for StreamPort {
    type Pose = pb::PoseSample;
    type Failure = Status;

    fn next(&mut self) -> Inbound {
        let next = self.poses.blocking_recv().unwrap_or(Inbound::Stopping);
        // Shutdown goes before poses already queued.
        if *self.stopped.borrow() {
            return Inbound::Stopping;
        }
        next
    }

    fn raw(&self, pose: &pb::PoseSample) -> Result<RawPose, PoseError> {
        convert::raw_pose(pose)
    }

    fn answer(&mut self, pose: &pb::PoseSample, a: Result<&ForceOut, Rejection<'_>>) -> bool {
        let reply = match a {
            Ok(out) => convert::force_sample(out),
            Err(Rejection::OverRate { rate_hz }) => convert::rejection(
                pose,
                tonic::Code::ResourceExhausted,
                format!("pose rate above {rate_hz:.0} Hz: pose not applied"),
            ),
            Err(Rejection::Pose(e)) => {
                convert::rejection(pose, convert::pose_error_code(e), e.to_string())
            }
        };
        answer(&self.tx, reply, &self.instrument)
    }

    /// E.g. a message over the size limit: the client gets the status.
    fn fail(&mut self, status: Status) {
        let _ = self.tx.try_send(Err(status));
    }

    fn stopping(&mut self) {
        let _ = self.tx.try_send(Err(shutting_down()));
    }
}
