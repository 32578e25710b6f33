//! `fissure-server`: loads a scene and serves `fissure.v1` over gRPC.

use anyhow::{Context, bail};
use clap::Parser;
use fissure_engine::scene::{DEFAULT_SCENE, Scene};
use fissure_engine::sim::{Mode, SimOptions, Simulation};
use fissure_server::recording::ToFile;
use fissure_server::{ServeOptions, Transport};
use std::net::SocketAddr;
use std::path::PathBuf;

/// Simulation server for training the opening of a brain fissure: owns the brain
/// model and the collision pipeline, takes spatula poses from haptic clients and
/// streams back reaction forces (about 1 kHz) and deformations.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Scene: an embedded name (cube, v-valley, u-valley, sylvian,
    /// interhemispheric) or a path to a scene TOML file.
    #[arg(long, default_value = DEFAULT_SCENE)]
    scene: String,
    /// Address to listen on. Only loopback addresses are accepted unless
    /// --allow-remote is given.
    #[arg(long, default_value = "127.0.0.1:50051")]
    listen: SocketAddr,
    /// Accept a non-loopback --listen address (exposes the server to the network;
    /// use with --token and TLS).
    #[arg(long)]
    allow_remote: bool,
    /// Bearer token clients must send (`authorization: Bearer <token>`) with the
    /// calls that change the simulation: Haptic (claiming an instrument) and
    /// Reset. The calls that only read need none. Also read from FISSURE_TOKEN.
    #[arg(long, env = "FISSURE_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// TLS certificate chain (PEM). Requires --tls-key.
    #[arg(long, requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// TLS private key (PEM). Requires --tls-cert.
    #[arg(long, requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// Run deformation steps on pose timestamps (deterministic), overriding the scene.
    #[arg(long)]
    stepped: bool,
    /// In stepped mode (this flag's or the scene's), how many instruments must
    /// be claimed before the first step.
    #[arg(long, default_value_t = 1)]
    stepped_clients: usize,
    /// Append the session (poses, forces, frame summaries) to this recording file.
    #[arg(long)]
    record: Option<PathBuf>,
    /// Largest number of concurrent watchers (Watch streams); one more is
    /// refused with RESOURCE_EXHAUSTED naming this limit.
    #[arg(long, default_value_t = 16)]
    max_watchers: usize,
    /// Nice value of the deformation thread and its pool (Linux; 0: unchanged).
    /// Above the force loops' so that a force sample preempts the solver.
    #[arg(long, default_value_t = fissure_engine::sim::DEFAULT_DEFORMATION_NICE)]
    deformation_nice: i32,
    /// Real-time priority (SCHED_FIFO, 1-99) each force loop asks for; 0 asks
    /// for none. Needs CAP_SYS_NICE or an RLIMIT_RTPRIO allowance; without it
    /// the loops run at normal priority (logged once).
    #[arg(long, default_value_t = fissure_engine::sim::runtime::priority::DEFAULT_FORCE_LOOP_RT_PRIORITY,
          value_parser = clap::value_parser!(u8).range(0..=99))]
    force_loop_rt_priority: u8,
    /// Real-time priority (SCHED_FIFO, 1-99) of the gRPC transport's threads,
    /// which read poses off the sockets and write force samples back; 0 asks
    /// for none. Keep it below --force-loop-rt-priority. Same privileges as
    /// the force loops; without them the transport runs at normal priority
    /// (logged once).
    #[arg(long, default_value_t = fissure_engine::sim::runtime::priority::DEFAULT_TRANSPORT_RT_PRIORITY,
          value_parser = clap::value_parser!(u8).range(0..=99))]
    transport_rt_priority: u8,
    /// Log filter (tracing's EnvFilter syntax), e.g. `info` or `fissure_server=debug`.
    #[arg(long, env = "FISSURE_LOG", default_value = "info")]
    log: String,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_new(&args.log).context("invalid --log filter")?,
        )
        .with_writer(std::io::stderr)
        .init();
    // Two runtimes: the transport serves the calls on real-time threads; this
    // one loads the scene, starts the simulation and waits for signals, at
    // normal priority (the simulation's threads inherit it).
    let transport =
        Transport::new(args.transport_rt_priority).context("starting the gRPC transport")?;
    tokio::runtime::Runtime::new()
        .context("starting the async runtime")?
        .block_on(run(args, &transport))
}

async fn run(args: Args, transport: &Transport) -> anyhow::Result<()> {
    if !args.listen.ip().is_loopback() && !args.allow_remote {
        bail!(
            "--listen {} is not a loopback address; pass --allow-remote to expose the server to the network",
            args.listen
        );
    }
    let tls = match (&args.tls_cert, &args.tls_key) {
        (Some(c), Some(k)) => Some((
            std::fs::read(c).with_context(|| format!("reading TLS certificate {}", c.display()))?,
            std::fs::read(k).with_context(|| format!("reading TLS key {}", k.display()))?,
        )),
        _ => None,
    };
    let (scene, _) =
        Scene::load(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    let server = transport
        .serve(
            args.listen,
            ServeOptions {
                token: args.token.clone(),
                tls,
            },
        )
        .await?;
    tracing::info!(addr = %server.addr, scene = %scene.name, "listening; loading the scene");
    let options = SimOptions {
        // --stepped-clients applies to a scene stepped by its file too.
        mode: (args.stepped || scene.loops.stepped).then_some(Mode::Stepped {
            clients: args.stepped_clients,
        }),
        recording: args.record.clone().map(ToFile::open_at),
        max_watchers: args.max_watchers,
        deformation_nice: args.deformation_nice,
        force_loop_rt_priority: args.force_loop_rt_priority,
    };
    let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options))
        .await?
        .context("starting the simulation")?;
    server.set_simulation(sim.clone()).await;
    tracing::info!("scene loaded; serving");
    shutdown_signal().await;
    tracing::info!("shutting down");
    server.shutdown().await?;
    tokio::task::spawn_blocking(move || {
        sim.shutdown();
        if let Some(rec) = sim.recorder() {
            rec.finish()
        } else {
            Ok(())
        }
    })
    .await?
    .context("completing the recording")?;
    Ok(())
}

async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}
