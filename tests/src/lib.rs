//! Helpers shared by the integration tests in `tests/tests/`: an in-process
//! server on `127.0.0.1:0` over a scene, and pose builders.

use fissure_engine::scene::Scene;
use fissure_engine::sim::{SimOptions, Simulation};
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_client::FissureClient;
use fissure_server::{RunningServer, ServeOptions, serve};
use std::sync::Arc;
use tonic::transport::Channel;

/// An in-process server.
#[derive(Debug)]
pub struct TestServer {
    /// `http://127.0.0.1:PORT` (`https://localhost:PORT` with TLS).
    pub url: String,
    /// The address it listens on.
    pub addr: std::net::SocketAddr,
    /// The simulation behind it.
    pub sim: Arc<Simulation>,
    server: Option<RunningServer>,
}

impl TestServer {
    /// Loads `scene` (embedded name or path) and serves it on a free loopback port.
    pub async fn start(
        scene: &str,
        options: SimOptions,
        serve_options: ServeOptions,
    ) -> anyhow::Result<Self> {
        let (scene, _) = Scene::load(scene)?;
        Self::start_scene(scene, options, serve_options).await
    }

    /// Serves an already parsed scene.
    pub async fn start_scene(
        scene: Scene,
        options: SimOptions,
        serve_options: ServeOptions,
    ) -> anyhow::Result<Self> {
        let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
        let tls = serve_options.tls.is_some();
        let server = serve("127.0.0.1:0".parse()?, serve_options).await?;
        server.set_simulation(sim.clone()).await;
        let addr = server.addr;
        Ok(Self {
            url: if tls {
                format!("https://localhost:{}", addr.port())
            } else {
                format!("http://{addr}")
            },
            addr,
            sim,
            server: Some(server),
        })
    }

    /// A connected client.
    pub async fn client(&self) -> anyhow::Result<FissureClient<Channel>> {
        fissure_cli::client::replay::connect(&self.url).await
    }

    /// Stops the server and the simulation.
    pub async fn stop(mut self) -> anyhow::Result<()> {
        if let Some(s) = self.server.take() {
            s.shutdown().await?;
        }
        let sim = self.sim.clone();
        tokio::task::spawn_blocking(move || sim.shutdown()).await?;
        Ok(())
    }
}

/// A pose message.
pub fn pose(t_s: f64, sequence: u64, position: [f64; 3], q: [f64; 4]) -> pb::PoseSample {
    pb::PoseSample::new(t_s, sequence, position, q)
}

/// A bidirectional haptic session for tests: send a pose, read its answer.
#[derive(Debug)]
pub struct Haptic {
    tx: tokio::sync::mpsc::Sender<pb::PoseSample>,
    rx: tonic::Streaming<pb::ForceSample>,
}

impl Haptic {
    /// Opens a haptic stream claiming `instrument`.
    pub async fn open(
        client: &mut FissureClient<Channel>,
        instrument: &str,
        token: Option<&str>,
    ) -> Result<Self, tonic::Status> {
        let (tx, rx) = tokio::sync::mpsc::channel(16);
        let req = fissure_cli::client::replay::haptic_request(
            tokio_stream::wrappers::ReceiverStream::new(rx),
            instrument,
            token,
        )
        .map_err(|e| tonic::Status::invalid_argument(e.to_string()))?;
        let rx = client.haptic(req).await?.into_inner();
        Ok(Self { tx, rx })
    }

    /// Sends one pose and waits for its force sample.
    pub async fn send(&mut self, pose: pb::PoseSample) -> anyhow::Result<pb::ForceSample> {
        self.tx.send(pose).await?;
        self.rx
            .message()
            .await?
            .ok_or_else(|| anyhow::anyhow!("the haptic stream ended"))
    }

    /// Sends one pose without waiting for its answer.
    pub async fn push(&mut self, pose: pb::PoseSample) -> anyhow::Result<()> {
        Ok(self.tx.send(pose).await?)
    }

    /// Waits for the next force sample.
    pub async fn next(&mut self) -> anyhow::Result<pb::ForceSample> {
        self.rx
            .message()
            .await?
            .ok_or_else(|| anyhow::anyhow!("the haptic stream ended"))
    }

    /// Closes the stream and waits until the server ends it.
    pub async fn close(mut self) {
        drop(self.tx);
        while let Ok(Some(_)) = self.rx.message().await {}
    }
}

/// Polls `GetStats` until the claimed instruments are exactly `expected` (scene
/// order), for at most 5 s; returns the last list seen either way.
pub async fn wait_until_claimed(
    client: &mut FissureClient<Channel>,
    expected: &[&str],
) -> anyhow::Result<Vec<String>> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        let claimed = client
            .get_stats(pb::GetStatsRequest {})
            .await?
            .into_inner()
            .claimed;
        if claimed == expected || std::time::Instant::now() > deadline {
            return Ok(claimed);
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
}
