//! The tonic adapter of `fissure.v1`: moves messages, holds no logic.
//!
//! The service answers `UNAVAILABLE` until the scene is loaded and factorized;
//! health reports `NOT_SERVING` until then, for the server as a whole (`""`,
//! what probes ask by default) and for `fissure.v1.Fissure`. With a token
//! ([`ServeOptions::token`]), the calls that change the simulation (`Haptic`,
//! `Reset`) need it; the calls that only read (`GetScene`, `GetSurface`,
//! `Watch`, `GetStats`), health and reflection are open. Each haptic stream gets its own
//! OS thread for its force loop: a 1 kHz loop should not share a scheduler
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
//! forever into a growing queue: after [`MAX_UNREAD_ANSWERS`] answers it has
//! not read, its stream ends with `RESOURCE_EXHAUSTED` (after the answers
//! already queued) and the instrument is released; the server logs it. Its
//! connection and the other streams on it keep working: the stream's pose
//! reader keeps reading until then, and each stream's receive window is
//! [`STREAM_RECEIVE_WINDOW_BYTES`], so that poses queued in the HTTP/2 layer
//! stay within its limits (with the default 1 MiB window, about 3,000
//! unread 100-byte poses made hyper's HTTP/2 layer end the whole connection
//! with GOAWAY `ENHANCE_YOUR_CALM`, "too_many_data_frames").

pub mod convert;
pub mod monitor;
pub mod reflection;
pub mod transport;

pub use transport::Transport;

use crate::sim::{ClaimError, Simulation};
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
/// 1,500 answers of 90 bytes: the stream ends after about 2.5 s of not
/// reading at 1 kHz). A client that pipelines its poses has a round trip's
/// worth unread at any time (tens at 1 kHz), far below it.
pub const MAX_UNREAD_ANSWERS: usize = 1024;

/// HTTP/2 receive window of each stream, bytes: the poses a stream's reader
/// has not taken yet that the HTTP/2 layer holds (about 700 poses). hyper's
/// default (1 MiB) let small pose frames exhaust its per-connection budget
/// for framing overhead (half the connection window) before flow control
/// pushed back, and it then closed the connection.
pub const STREAM_RECEIVE_WINDOW_BYTES: u32 = 64 * 1024;

/// Longest wait, after the streams are ended, for connections to close at
/// shutdown before they are dropped.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// Sustained pose rate a haptic stream is served at in free-running mode, as
/// a multiple of the scene's `loops.haptic_rate_hz` (2 kHz for a 1 kHz scene).
/// Poses above it are answered at once with a `RESOURCE_EXHAUSTED` rejection
/// (nothing computed, nothing applied), so a flooding client cannot take more
/// than its share of the CPU from the other client and the deformation loop.
/// Stepped mode has no limit: its force loop waits for the deformation loop.
pub const MAX_POSE_RATE_FACTOR: f64 = 2.0;

/// Burst a haptic stream may send above the sustained rate, seconds of poses
/// at that rate (2000 poses at 2 kHz): a 1 kHz client whose poses queued up
/// during a stall of up to 2 s (network, scheduling) drains its backlog
/// without a rejection.
pub const POSE_BURST_S: f64 = 1.0;

/// A token bucket over wall-clock time: `rate` poses a second sustained,
/// `rate * POSE_BURST_S` at once.
#[derive(Debug)]
struct PoseBudget {
    rate_hz: f64,
    tokens: f64,
    capacity: f64,
    last: std::time::Instant,
}

impl PoseBudget {
    fn new(rate_hz: f64) -> Self {
        let capacity = (rate_hz * POSE_BURST_S).max(1.0);
        Self {
            rate_hz,
            tokens: capacity,
            capacity,
            last: std::time::Instant::now(),
        }
    }

    /// Takes one pose from the budget; false when the stream is over its rate.
    fn take(&mut self) -> bool {
        self.take_at(std::time::Instant::now())
    }

    fn take_at(&mut self, now: std::time::Instant) -> bool {
        let dt = now.duration_since(self.last).as_secs_f64();
        self.last = now;
        self.tokens = (self.tokens + dt * self.rate_hz).min(self.capacity);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

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

/// Queues one answer of a haptic stream; false when the stream is over: the
/// client went away, or it left [`MAX_UNREAD_ANSWERS`] answers unread (then
/// the last slot of the queue, kept for it, carries the status saying so).
fn answer(
    tx: &tokio::sync::mpsc::Sender<Result<pb::ForceSample, Status>>,
    reply: pb::ForceSample,
    instrument: &str,
) -> bool {
    if tx.capacity() > 1 {
        return tx.try_send(Ok(reply)).is_ok();
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
        let mut claim = sim.claim(&name).map_err(|e| match e {
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
        let mut budget = (!sim.is_stepped())
            .then(|| PoseBudget::new(MAX_POSE_RATE_FACTOR * sim.scene().loops.haptic_rate_hz));
        // The stream is read on the runtime, by a task of its own: the force
        // loop's thread only takes decoded poses from a channel.
        let (pose_tx, mut pose_rx) = tokio::sync::mpsc::channel::<Inbound>(64);
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
        std::thread::Builder::new()
            .name(format!("force-loop-{name}"))
            .spawn(move || {
                // The claim lives on this thread and is released when it ends.
                claim.enter_force_thread();
                loop {
                    let mut next = pose_rx.blocking_recv().unwrap_or(Inbound::Stopping);
                    // Shutdown goes before poses already queued.
                    if *stopped.borrow() {
                        next = Inbound::Stopping;
                    }
                    let msg = match next {
                        Inbound::Pose(m) => m,
                        Inbound::End => break,
                        Inbound::Failed(status) => {
                            // E.g. a message over the size limit: the client
                            // gets the status, the claim is released.
                            tracing::debug!(instrument = %name, %status, "haptic stream ended with an error");
                            let _ = tx.try_send(Err(status));
                            break;
                        }
                        Inbound::Stopping => {
                            let _ = tx.try_send(Err(shutting_down()));
                            break;
                        }
                    };
                    let over_rate = budget.as_mut().is_some_and(|b| !b.take());
                    if let Some(b) = budget.as_ref().filter(|_| over_rate) {
                        sim.record_rejection();
                        let reply = convert::rejection(
                            &msg,
                            tonic::Code::ResourceExhausted,
                            format!(
                                "pose rate above {:.0} Hz: pose not applied",
                                b.rate_hz
                            ),
                        );
                        if !answer(&tx, reply, &name) {
                            break;
                        }
                        continue;
                    }
                    let raw = convert::raw_pose(&msg);
                    if raw.is_err() {
                        sim.record_rejection();
                    }
                    let reply = match raw.and_then(|raw| claim.force_sample(&raw)) {
                        Ok(out) => {
                            let sample = convert::force_sample(&out);
                            if let Some(rec) = sim.recorder() {
                                rec.pose(&name, msg);
                                rec.force(&name, sample.clone());
                            }
                            sample
                        }
                        Err(e) => {
                            tracing::debug!(instrument = %name, error = %e, "pose rejected");
                            convert::rejection(&msg, convert::pose_error_code(&e), e.to_string())
                        }
                    };
                    if !answer(&tx, reply, &name) {
                        break;
                    }
                }
                drop(claim);
            })
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
                Ok(convert::frame(&frame, include))
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
enum Inbound {
    /// The next pose.
    Pose(pb::PoseSample),
    /// The client ended its stream.
    End,
    /// The stream failed (e.g. a message over the size limit).
    Failed(Status),
    /// The server is shutting down.
    Stopping,
}

#[cfg(test)]
mod tests {
    use super::{POSE_BURST_S, PoseBudget};
    use std::time::{Duration, Instant};

    /// A flood gets the burst, then the sustained rate; a stream at the rate
    /// is never refused; a stall refills at most the burst.
    #[test]
    fn pose_budget_allows_the_rate_and_the_burst_only() {
        let rate = 2000.0;
        let burst = (rate * POSE_BURST_S) as usize;
        let t0 = Instant::now();
        let mut b = PoseBudget::new(rate);
        b.last = t0;
        // 10 kHz for 2 s: burst + 2 s at 2 kHz served (within one pose).
        let served = (0..20_000)
            .filter(|&i| b.take_at(t0 + Duration::from_micros(100 * i)))
            .count();
        let expected = burst + 2 * rate as usize;
        assert!(served.abs_diff(expected) <= 1, "{served} vs {expected}");
        // At 1 kHz after a 10 s pause: every pose served.
        let t1 = t0 + Duration::from_secs(12);
        assert!((0..5_000).all(|i| b.take_at(t1 + Duration::from_millis(i))));
        // A 1.5 s stall at 1 kHz, then the 1500 queued poses at once: served.
        let t2 = t1 + Duration::from_millis(5_000 + 1_500);
        assert!((0..1_500).all(|_| b.take_at(t2)));
        // The budget is then empty: the next pose at the same instant is not.
        let mut empty = PoseBudget::new(rate);
        empty.last = t0;
        assert!((0..burst).all(|_| empty.take_at(t0)));
        assert!(!empty.take_at(t0));
    }
}
