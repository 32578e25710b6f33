//! `fissure`: the command-line client of the fissure simulation server.

use anyhow::Context;
use clap::{Parser, Subcommand};
use fissure_cli::client::replay::{Pacing, connect, forces_csv, replay};
use fissure_cli::client::trajectory::Trajectory;
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
    #[cfg(feature = "lab")]
    Demo(fissure_cli::lab::demo::DemoArgs),
    /// Stream trajectories to a server as haptic clients (one per instrument)
    /// and write the forces per instrument.
    #[command(after_help = REPLAY_HELP)]
    Replay(ReplayArgs),
    /// Bridge UDP pose datagrams of haptic device programs (or, with
    /// --igtl-listen / --igtl-connect, OpenIGTLink peers such as 3D Slicer
    /// and PLUS) to the server's haptic streams; forces go back to the sender.
    #[command(after_help = BRIDGE_HELP)]
    Bridge(fissure_cli::client::bridge::BridgeArgs),
    /// Subscribe to deformation frames; write a VTU series (+ .pvd for
    /// ParaView), PNG images and an animated GIF.
    Watch(fissure_cli::client::watch::WatchArgs),
    /// Build, convert and inspect brain models.
    #[cfg(feature = "lab")]
    Mesh {
        #[command(subcommand)]
        command: fissure_cli::lab::mesh::MeshCommand,
    },
    /// Make scenes: a patient's brain from an image, with the fissure to
    /// open found near a point.
    #[cfg(feature = "lab")]
    Scene {
        #[command(subcommand)]
        command: fissure_cli::lab::scene::SceneCommand,
    },
    /// Benchmarks (print a table, or JSON with --json).
    #[cfg(feature = "lab")]
    Bench {
        #[command(subcommand)]
        which: Bench,
    },
    /// Summarise and assess a session recording: duration, peak and mean
    /// force per instrument, time above a safe-force threshold, path length,
    /// time in contact; the retraction pressure, the tissue's strain and the
    /// injuries, each scored against the scene's thresholds (pass, warn,
    /// fail); and with `--html` a page a teacher opens in a browser.
    Report {
        /// The recording (`.fsrec`, written by `fissure-server --record` or the demo).
        file: PathBuf,
        /// Safe-force threshold, N.
        #[arg(long, default_value_t = 1.0)]
        threshold_n: f64,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Also write one self-contained HTML page (scores, plots against
        /// time with the thresholds, the brain at the worst strain, the
        /// events); nothing in it is fetched from the network.
        #[arg(long, value_name = "OUT.html")]
        html: Option<PathBuf>,
        /// Another session (an expert's) to put beside this one: the same
        /// measures in the tables, the same axes in the plots.
        #[arg(long, value_name = "EXPERT.fsrec")]
        compare: Option<PathBuf>,
        /// Report the entries before a truncated last entry (a recorder
        /// stopped mid-write) instead of refusing the file.
        #[arg(long)]
        accept_truncated: bool,
    },
    /// Speed against accuracy of the simulation's configurations on the
    /// scripted Sylvian opening, and stability at the extremes (CSV,
    /// markdown, PNG plots). Alone it runs the whole study here; `plan`,
    /// `run` and `merge` run it anywhere, e.g. as a Slurm job array
    /// (client-cli/slurm/study.sbatch).
    #[cfg(feature = "lab")]
    Study(fissure_cli::lab::study::StudyCommand),
    /// Ask a server's grpc.health.v1 whether it is serving; exits non-zero if not.
    Health {
        /// Server URL.
        #[arg(long, default_value = "http://127.0.0.1:50051")]
        server: String,
    },
}

#[cfg(feature = "lab")]
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
        /// Element formulations (tet4, tet4-nodal-pressure); both by default,
        /// corotational runs tet4 only.
        #[arg(long, value_delimiter = ',')]
        element: Vec<String>,
        /// Timed steps per row.
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Also run each row with an elastic foundation of this
        /// stiffness, Pa/m, on the outer triangles beyond 25 mm of the top
        /// centre (the bundled scenes use 1.145e10), beside the stem-only
        /// row on the same contact set, with their ratio.
        #[arg(long)]
        foundation_pa_per_m: Option<f64>,
        /// Print JSON rows instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Force-loop latency under load: an in-process free-running server, one
    /// haptic client per instrument at 1 kHz on real-time ticks, and watchers;
    /// round trip, server compute time, missed samples, deformation rate.
    Loop(fissure_cli::lab::bench::loops::LoopBenchArgs),
    /// Collision query time, brute force against the refitted BVH, CPU and GPU
    /// rows side by side, with two spatulas in the left Sylvian fissure of a
    /// phantom preset (or on a box of the paper's size): ms per query, speedup.
    Collision(fissure_cli::lab::bench::collision::CollisionArgs),
    /// The rays of `bench collision --dump-rays` cast again by the CPU BVH,
    /// one thread by default: ns per line bounded and whole, bundled and per
    /// ray, build and refit (the figures the Embree comparison sets beside
    /// its own).
    Rays(fissure_cli::lab::bench::rays::RaysArgs),
    /// Force samples against a full solve at every sample, on every scene
    /// with bundled trajectories (stepped, 1 kHz): error, ripple at frame
    /// changes, onset, press/retract hysteresis, normal force, settling of
    /// held poses, model age and cost, beside their targets.
    Haptic(fissure_cli::lab::bench::haptic::HapticArgs),
    /// Latency the device bridges add to a force round trip: direct gRPC,
    /// the UDP bridge and the OpenIGTLink bridge (with and without the
    /// surface stream), lockstep at 1 kHz on the cube scene.
    Bridge(fissure_cli::lab::bench::bridge::BridgeBenchArgs),
}

const REPLAY_HELP: &str = "\
Trajectory files (s, m, unit quaternion w x y z; the pose of the instrument's
handle point in the scene frame):
  one instrument   CSV `t_s,x_m,y_m,z_m,qw,qx,qy,qz`, or JSON
                   [{\"t_s\":0,\"x_m\":..,\"y_m\":..,\"z_m\":..,\"qw\":..,\"qx\":..,\"qy\":..,\"qz\":..}, ...]
  several          CSV `instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz` (rows may interleave),
                   or JSON {\"left\": [waypoints...], \"right\": [...]}
Errors name the file, the line and the column.

Examples:
  fissure replay --instrument left --trajectory sylvian-open-left
  fissure replay --trajectory left=l.csv --trajectory right=r.json --pacing fast
  fissure replay --trajectory both.csv --out run/forces.csv   (writes run/forces-left.csv, ...)

Stepped mode is the server's: start it with `fissure-server --stepped
--stepped-clients N` and the deformation steps follow the pose timestamps,
so `--pacing fast` gives the same forces every run, whatever the speed.";

const BRIDGE_HELP: &str = "\
Pose datagram (binary, little-endian, 80 bytes):
  0 magic b\"FSP1\" | 4 u8 version=1 | 5 u8 instrument index | 6 u16 reserved=0
  8 u64 sequence | 16 f64 t_s (s) | 24 3xf64 position (m) | 48 4xf64 quaternion w,x,y,z
Force datagram back to the sender (112 bytes):
  0 magic b\"FSF1\" | 4 u8 version=1 | 5 u8 instrument | 6 u16 status (0 ok, 1 rejected,
  2 not forwarded) | 8 u64 sequence | 16 f64 t_s | 24 3xf64 force (N) | 48 3xf64 torque (N m)
  72 u32 contact count | 76 u32 safety flags | 80 u64 model frame | 88 f64 model age (s)
  96 f64 server compute (us) | 104 u64 reserved
JSON form (one object per datagram):
  {\"instrument\":\"left\",\"seq\":7,\"t_s\":0.007,\"p\":[x,y,z],\"q\":[w,x,y,z]}   (or \"i\":0)
  answered by one line {\"instrument\":..,\"seq\":..,\"status\":\"ok\",\"f\":[..],\"torque\":[..],...}
Instrument indices follow the order of --instrument, or the scene's order.
Sequence numbers must increase and times must not go back, per instrument.
With --tie-events (scenes with ties), each device that has sent a pose also gets one
datagram per tie cut or torn (64 bytes):
  0 magic b\"FST1\" | 4 u8 version=1 | 5 u8 instrument (255: not bridged) | 6 u8 kind
  (1 trabecula, 2 vessel) | 7 u8 cause (1 cut, 2 torn, 0 released unseen) | 8 u32 tie
  16 f64 t_s | 24 3xf64 midpoint (m) | 48 f64 strain | or, to JSON devices, one line
  {\"event\":\"tie\",\"tie\":4,\"cause\":\"cut\",\"kind\":\"trabecula\",...}

OpenIGTLink (--igtl-listen [ADDR] or --igtl-connect HOST:PORT, instead of UDP):
  in   TRANSFORM or POSITION, device name = instrument (or --igtl-map DEVICE=INSTRUMENT),
       sender units (--igtl-unit-m, default 0.001 = mm) in the sender's frame;
       scene position = unit_m * (R p + t) with --igtl-registration (4x4, row major)
  out  SENSOR <instrument>_force (N, 3 values) and <instrument>_torque (N m), per pose,
       in the sender's frame, with the pose's timestamp; STATUS on rejections and
       safety-flag changes; POLYDATA --igtl-surface-device (mm, triangles first);
       STATUS --igtl-ties-device per tie cut or torn (TIE_CUT, TIE_TORN, VESSEL_TORN)
Examples:
  fissure bridge --igtl-listen        (3D Slicer connects to localhost:18944)
  fissure bridge --igtl-connect plus-host:18944 --igtl-map StylusToReference=left";

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    server: String,
    /// Instrument to claim (as named by the scene), with one --trajectory
    /// FILE. Without it, name instruments in --trajectory NAME=FILE or use a
    /// file of several instruments.
    #[arg(long, conflicts_with = "recording")]
    instrument: Option<String>,
    /// Trajectory: FILE (CSV or JSON, see below), the name of a bundled
    /// trajectory, or NAME=FILE to give an instrument its own (repeatable).
    #[arg(
        long,
        conflicts_with = "recording",
        required_unless_present = "recording"
    )]
    trajectory: Vec<String>,
    /// Replay every instrument's accepted poses from a session recording, all
    /// instruments at once (instead of --instrument/--trajectory).
    #[arg(long)]
    recording: Option<PathBuf>,
    /// Output CSV of force samples (N, N m, us). With several instruments,
    /// one file per instrument named `<stem>-<instrument>.csv` beside it.
    #[arg(long, default_value = "forces.csv")]
    out: PathBuf,
    /// Pose pacing: `realtime` sends each pose at its timestamp; `fast` sends
    /// the next pose as soon as the previous force came back. (Stepped,
    /// reproducible stepping is a server mode: `fissure-server --stepped`.)
    #[arg(long, value_enum, default_value_t = Pacing::Realtime)]
    pacing: Pacing,
    /// Bearer token for the claim (also FISSURE_TOKEN).
    #[arg(long, env = "FISSURE_TOKEN", hide_env_values = true)]
    token: Option<String>,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    {
        use tracing_subscriber::Layer;
        use tracing_subscriber::layer::SubscriberExt;
        use tracing_subscriber::util::SubscriberInitExt;
        // Log lines (FISSURE_LOG, warnings by default) and, beside them, a
        // spinner for the progress of long work (scene loading, meshing).
        let log = tracing_subscriber::fmt::layer()
            .with_writer(std::io::stderr)
            .with_filter(
                tracing_subscriber::EnvFilter::try_from_env("FISSURE_LOG")
                    .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
            );
        let registry = tracing_subscriber::registry().with(log);
        // Progress events come from engine work in process (lab commands).
        #[cfg(feature = "lab")]
        let registry = {
            use fissure_cli::lab::progress::ProgressLayer;
            registry.with(ProgressLayer::stderr().with_filter(ProgressLayer::filter()))
        };
        registry.init();
    }
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    match cli.command {
        #[cfg(feature = "lab")]
        Command::Study(cmd) => fissure_cli::lab::study::command(&cmd)?,
        #[cfg(feature = "lab")]
        Command::Demo(args) => {
            rt.block_on(fissure_cli::lab::demo::run(&args))?;
        }
        Command::Replay(args) => {
            let set = match &args.recording {
                Some(rec) => fissure_cli::client::report::trajectories(rec)?,
                None => fissure_cli::client::trajectory::resolve(
                    args.instrument.as_deref(),
                    &args.trajectory,
                )?,
            };
            let stem = args
                .out
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("forces")
                .to_owned();
            let several = set.len() > 1;
            let plans: Vec<(String, Trajectory, PathBuf)> = set
                .into_iter()
                .map(|(name, t)| {
                    let out = if several || args.recording.is_some() {
                        args.out.with_file_name(format!("{stem}-{name}.csv"))
                    } else {
                        args.out.clone()
                    };
                    (name, t, out)
                })
                .collect();
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
        Command::Bridge(args) => {
            rt.block_on(fissure_cli::client::bridge::run(&args))?;
        }
        Command::Watch(args) => {
            rt.block_on(fissure_cli::client::watch::run(&args))?;
        }
        #[cfg(feature = "lab")]
        Command::Mesh { command } => fissure_cli::lab::mesh::run(command)?,
        #[cfg(feature = "lab")]
        Command::Scene { command } => fissure_cli::lab::scene::run(command)?,
        #[cfg(feature = "lab")]
        Command::Bench { which } => match which {
            Bench::Fem {
                preset,
                contacts,
                strategy,
                element,
                steps,
                foundation_pa_per_m,
                json,
            } => {
                use fissure_cli::lab::bench::fem::{
                    FemBenchOptions, Support, print, run_fem_bench,
                };
                let mut opts = FemBenchOptions {
                    contact_counts: contacts,
                    steps,
                    ..Default::default()
                };
                if let Some(k) = foundation_pa_per_m {
                    anyhow::ensure!(
                        k.is_finite() && k > 0.0,
                        "--foundation-pa-per-m: a stiffness per area must be finite and > 0 Pa/m (got {k})"
                    );
                    opts.supports.push(Support::Foundation {
                        stiffness_pa_per_m: k,
                    });
                }
                if !strategy.is_empty() {
                    opts.strategies = strategy
                        .iter()
                        .map(|s| s.parse().map_err(|e| anyhow::anyhow!("--strategy: {e}")))
                        .collect::<anyhow::Result<_>>()?;
                }
                if !element.is_empty() {
                    opts.elements = element
                        .iter()
                        .map(|s| s.parse().map_err(|e| anyhow::anyhow!("--element: {e}")))
                        .collect::<anyhow::Result<_>>()?;
                }
                let mut rows = Vec::new();
                for name in &preset {
                    let phantom = fissure_engine::mesh::phantom::preset(name)
                        .with_context(|| format!("--preset {name}"))?;
                    rows.extend(run_fem_bench(&phantom.mesh, name, &opts));
                }
                print(&rows, json);
            }
            Bench::Loop(args) => rt.block_on(fissure_cli::lab::bench::loops::main(&args))?,
            Bench::Collision(args) => fissure_cli::lab::bench::collision::run(&args)?,
            Bench::Rays(args) => fissure_cli::lab::bench::rays::run(&args)?,
            Bench::Haptic(args) => fissure_cli::lab::bench::haptic::main(&args)?,
            Bench::Bridge(args) => rt.block_on(fissure_cli::lab::bench::bridge::main(&args))?,
        },
        Command::Report {
            file,
            threshold_n,
            json,
            html,
            compare,
            accept_truncated,
        } => {
            let options = fissure_cli::client::report::Options {
                threshold_n,
                accept_truncated,
            };
            print!(
                "{}",
                fissure_cli::client::report::command(
                    &file,
                    &options,
                    json,
                    html.as_deref(),
                    compare.as_deref()
                )?
            );
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
