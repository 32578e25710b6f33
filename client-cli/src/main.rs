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
    /// Build, convert and inspect brain models.
    Mesh {
        #[command(subcommand)]
        command: fissure_cli::mesh_cmd::MeshCommand,
    },
    /// Benchmarks (print a table, or JSON with --json).
    Bench {
        #[command(subcommand)]
        which: Bench,
    },
    /// Summarise a session recording: duration, peak and mean force per
    /// instrument, time above a safe-force threshold, path length, time in contact.
    Report {
        /// The recording (`.fsrec`, written by `fissure-server --record` or the demo).
        file: PathBuf,
        /// Safe-force threshold, N.
        #[arg(long, default_value_t = 1.0)]
        threshold_n: f64,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Speed against accuracy of the simulation's configurations on the
    /// scripted Sylvian opening, and stability at the extremes (CSV,
    /// markdown, PNG plots).
    Study(fissure_cli::study::StudyArgs),
    /// Ask a server's grpc.health.v1 whether it is serving; exits non-zero if not.
    Health {
        /// Server URL.
        #[arg(long, default_value = "http://127.0.0.1:50051")]
        server: String,
    },
}

#[derive(Debug, Subcommand)]
enum Bench {
    /// Time per deformation step of each solver strategy on a phantom preset,
    /// with a growing contact set (ms per step).
    Fem {
        /// Phantom preset(s) to run (coarse, paper-34k, paper-48k).
        #[arg(long, default_values_t = ["paper-48k".to_string()])]
        preset: Vec<String>,
        /// Contact-set sizes (surface vertices).
        #[arg(long, value_delimiter = ',', default_values_t = [10usize, 50, 200])]
        contacts: Vec<usize>,
        /// Strategies (direct, compliance, corotational, neo-hookean); all by default.
        #[arg(long, value_delimiter = ',')]
        strategy: Vec<String>,
        /// Timed steps per row.
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Print JSON rows instead of a table.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    server: String,
    /// Instrument to claim (as named by the scene). Required with --trajectory.
    #[arg(long, required_unless_present = "recording", requires = "trajectory")]
    instrument: Option<String>,
    /// Trajectory: a CSV file (`t_s,x_m,y_m,z_m,qw,qx,qy,qz`; s, m, unit
    /// quaternion), a JSON file (array of objects with those keys), or the name
    /// of a bundled trajectory.
    #[arg(long, conflicts_with = "recording")]
    trajectory: Option<String>,
    /// Replay every instrument's accepted poses from a session recording, all
    /// instruments at once (instead of --instrument/--trajectory).
    #[arg(long)]
    recording: Option<PathBuf>,
    /// Output CSV of force samples (N, N m, us). With --recording, one file per
    /// instrument named `<stem>-<instrument>.csv`.
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
        Command::Study(args) => fissure_cli::study::run(&args)?,
        Command::Demo(args) => {
            rt.block_on(fissure_cli::demo::run(&args))?;
        }
        Command::Replay(args) => {
            let plans: Vec<(String, Trajectory, PathBuf)> =
                match (&args.recording, &args.trajectory, &args.instrument) {
                    (Some(rec), _, _) => {
                        let stem = args
                            .out
                            .file_stem()
                            .and_then(|s| s.to_str())
                            .unwrap_or("forces")
                            .to_owned();
                        fissure_cli::report::trajectories(rec)?
                            .into_iter()
                            .map(|(name, t)| {
                                let out = args.out.with_file_name(format!("{stem}-{name}.csv"));
                                (name, t, out)
                            })
                            .collect()
                    }
                    (None, Some(t), Some(i)) => {
                        vec![(i.clone(), Trajectory::load(t)?, args.out.clone())]
                    }
                    _ => anyhow::bail!("give --instrument and --trajectory, or --recording"),
                };
            rt.block_on(async {
                let mut tasks = Vec::new();
                for (name, trajectory, out) in plans {
                    let (server, token, pacing) =
                        (args.server.clone(), args.token.clone(), args.pacing);
                    tasks.push(tokio::spawn(async move {
                        let mut client = connect(&server).await?;
                        let rows = replay(
                            &mut client,
                            &name,
                            token.as_deref(),
                            &trajectory,
                            pacing,
                            |_| {},
                        )
                        .await?;
                        std::fs::write(&out, forces_csv(&rows))
                            .with_context(|| format!("writing {}", out.display()))?;
                        eprintln!(
                            "{name}: {} force samples written to {}",
                            rows.len(),
                            out.display()
                        );
                        anyhow::Ok(())
                    }));
                }
                for t in tasks {
                    t.await??;
                }
                anyhow::Ok(())
            })?;
        }
        Command::Mesh { command } => fissure_cli::mesh_cmd::run(command)?,
        Command::Bench { which } => match which {
            Bench::Fem {
                preset,
                contacts,
                strategy,
                steps,
                json,
            } => {
                use fissure_cli::bench_fem::{FemBenchOptions, print, run_fem_bench};
                let mut opts = FemBenchOptions {
                    contact_counts: contacts,
                    steps,
                    ..Default::default()
                };
                if !strategy.is_empty() {
                    opts.strategies = strategy
                        .iter()
                        .map(|s| s.parse().map_err(|e| anyhow::anyhow!("--strategy: {e}")))
                        .collect::<anyhow::Result<_>>()?;
                }
                let mut rows = Vec::new();
                for name in &preset {
                    let phantom = fissure_server::mesh::phantom::preset(name)
                        .with_context(|| format!("--preset {name}"))?;
                    rows.extend(run_fem_bench(&phantom.mesh, name, &opts));
                }
                print(&rows, json);
            }
        },
        Command::Report {
            file,
            threshold_n,
            json,
        } => {
            let r = fissure_cli::report::report(&file, threshold_n)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                print!("{}", fissure_cli::report::table(&r));
            }
        }
        Command::Health { server } => {
            use tonic_health::pb::health_check_response::ServingStatus;
            let status = rt.block_on(async {
                let channel = tonic::transport::Channel::from_shared(server.clone())
                    .with_context(|| format!("invalid server URL {server:?}"))?
                    .connect()
                    .await
                    .with_context(|| format!("cannot connect to {server}"))?;
                let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
                let req = tonic_health::pb::HealthCheckRequest {
                    service: "fissure.v1.Fissure".into(),
                };
                anyhow::Ok(health.check(req).await?.into_inner().status)
            })?;
            let status = ServingStatus::try_from(status).unwrap_or(ServingStatus::Unknown);
            println!("{}", status.as_str_name());
            if status != ServingStatus::Serving {
                std::process::exit(1);
            }
        }
    }
    Ok(())
}
