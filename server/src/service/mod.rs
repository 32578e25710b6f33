//! The tonic adapter of `fissure.v1`: moves messages, holds no logic.
//!
//! The service answers `UNAVAILABLE` until the scene is loaded and factorized
//! (health reports `NOT_SERVING` until then). Each haptic stream gets its own
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

pub mod convert;
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
use tonic::{Request, Response, Status, Streaming};

/// Largest message accepted from a client, bytes (poses are ~100 bytes).
pub const MAX_DECODING_MESSAGE_BYTES: usize = 64 * 1024;

/// Largest message sent, bytes (a frame of a 16k-vertex surface is ~200 kB).
pub const MAX_ENCODING_MESSAGE_BYTES: usize = 16 * 1024 * 1024;

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
    /// Bearer token required to claim an instrument, if any.
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

    fn check_token<T>(&self, req: &Request<T>) -> Result<(), Status> {
        let Some(token) = &self.token else {
            return Ok(());
        };
        let given = req
            .metadata()
            .get(AUTHORIZATION_METADATA_KEY)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        match given {
            Some(g) if constant_time_eq(g.as_bytes(), token.as_bytes()) => Ok(()),
            Some(_) => Err(Status::unauthenticated("the bearer token is wrong")),
            None => Err(Status::unauthenticated(
                "this server requires `authorization: Bearer <token>` to claim an instrument",
            )),
        }
    }
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
        _: Request<pb::ResetRequest>,
    ) -> Result<Response<pb::ResetResponse>, Status> {
        Ok(Response::new(pb::ResetResponse {
            frame: self.sim()?.reset(),
        }))
    }

    type HapticStream = BoxStream<pb::ForceSample>;

    async fn haptic(
        &self,
        req: Request<Streaming<pb::PoseSample>>,
    ) -> Result<Response<Self::HapticStream>, Status> {
        let sim = self.sim()?.clone();
        self.check_token(&req)?;
        if *self.stopping.borrow() {
            return Err(shutting_down());
        }
        let name = req
            .metadata()
            .get(INSTRUMENT_METADATA_KEY)
            .ok_or_else(|| {
                Status::invalid_argument(format!(
                    "the `{INSTRUMENT_METADATA_KEY}` metadata naming the instrument is missing"
                ))
            })?
            .to_str()
            .map_err(|_| {
                Status::invalid_argument(format!("`{INSTRUMENT_METADATA_KEY}` is not ASCII"))
            })?
            .to_owned();
        let mut claim = sim.claim(&name).map_err(|e| match e {
            ClaimError::Unknown { .. } => Status::not_found(e.to_string()),
            ClaimError::Taken(_) => Status::already_exists(e.to_string()),
            ClaimError::ShuttingDown => Status::unavailable(e.to_string()),
        })?;
        let mut inbound = req.into_inner();
        let (tx, rx) = tokio::sync::mpsc::channel::<Result<pb::ForceSample, Status>>(64);
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
                            let _ = tx.blocking_send(Err(status));
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
                        if tx.blocking_send(Ok(reply)).is_err() {
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
                            convert::rejection(&msg, tonic::Code::InvalidArgument, e.to_string())
                        }
                    };
                    if tx.blocking_send(Ok(reply)).is_err() {
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
        let guard = sim
            .watch()
            .ok_or_else(|| Status::resource_exhausted("the server's watcher limit is reached"))?;
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
    /// Makes the simulation available and reports SERVING.
    pub async fn set_simulation(&self, sim: Arc<Simulation>) {
        self.service.set_simulation(sim);
        self.health
            .set_serving::<FissureServer<FissureService>>()
            .await;
    }

    /// Ends the open streams, stops accepting calls and waits (at most
    /// [`SHUTDOWN_GRACE`]) for the connections to close; then drops them.
    pub async fn shutdown(mut self) -> anyhow::Result<()> {
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

/// Binds `addr` and serves `fissure.v1`, health and reflection. Health says
/// NOT_SERVING until [`RunningServer::set_simulation`].
pub async fn serve(addr: SocketAddr, options: ServeOptions) -> anyhow::Result<RunningServer> {
    use anyhow::Context;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let addr = listener.local_addr()?;
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_not_serving::<FissureServer<FissureService>>()
        .await;
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(fissure_proto::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1()
        .context("building the reflection service")?;
    let service = FissureService::new(options.token.clone());
    let grpc = FissureServer::new(service.clone())
        .max_decoding_message_size(MAX_DECODING_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_ENCODING_MESSAGE_BYTES);
    let mut builder = tonic::transport::Server::builder().tcp_nodelay(true);
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
        .add_service(reflection)
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
