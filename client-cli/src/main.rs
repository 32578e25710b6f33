//! `fissure`: the command-line client of the fissure simulation server.

use anyhow::Context;
use clap::{Parser, Subcommand};
use fissure_cli::replay::{Pacing, connect, forces_csv, replay};
use fissure_cli::trajectory::Trajectory;
use std::path::PathBuf;

/// Client of the fissure brain-fissure simulation server: replay trajectories,
/// run the demo, build and inspect brain models, benchmark.
#[derive(Debug, Parser)]
#[command(version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Start a server in-process, drive both spatulas with the bundled
    /// trajectories and write a results folder.
    Demo(fissure_cli::demo::DemoArgs),
    /// Stream a trajectory to a server as one haptic client and write the forces.
    Replay(ReplayArgs),
}

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    server: String,
    /// Instrument to claim (as named by the scene).
    #[arg(long)]
    instrument: String,
    /// Trajectory: a CSV file (`t_s,x_m,y_m,z_m,qw,qx,qy,qz`; s, m, unit
    /// quaternion), a JSON file (array of objects with those keys), or the name
    /// of a bundled trajectory.
    #[arg(long)]
    trajectory: String,
    /// Output CSV of force samples (N, N m, us).
    #[arg(long, default_value = "forces.csv")]
    out: PathBuf,
    /// Pose pacing.
    #[arg(long, value_enum, default_value_t = Pacing::Realtime)]
    pacing: Pacing,
    /// Bearer token for the claim (also FISSURE_TOKEN).
    #[arg(long, env = "FISSURE_TOKEN", hide_env_values = true)]
    token: Option<String>,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("FISSURE_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    match cli.command {
        Command::Demo(args) => {
            rt.block_on(fissure_cli::demo::run(&args))?;
        }
        Command::Replay(args) => {
            let trajectory = Trajectory::load(&args.trajectory)?;
            let rows = rt.block_on(async {
                let mut client = connect(&args.server).await?;
                replay(&mut client, &args.instrument, args.token.as_deref(), &trajectory, args.pacing, |_| {}).await
            })?;
            std::fs::write(&args.out, forces_csv(&rows)).with_context(|| format!("writing {}", args.out.display()))?;
            eprintln!("{} force samples written to {}", rows.len(), args.out.display());
        }
    }
    Ok(())
}
