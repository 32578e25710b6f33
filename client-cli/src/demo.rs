//! `fissure demo`: starts the server in-process on loopback, drives every
//! instrument of the scene with its bundled trajectory at the same time, and
//! writes a results folder a person can look at.

use crate::replay::{ForceRow, Pacing, connect, forces_csv, replay};
use crate::trajectory::{BUNDLED, Trajectory};
use anyhow::{Context, bail};
use fissure_proto::v1 as pb;
use fissure_server::scene::Scene;
use fissure_server::service::{ServeOptions, serve};
use fissure_server::sim::stats::percentile;
use fissure_server::sim::{SimOptions, Simulation};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Options of the demo.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// Scene to run (an embedded name); it must have bundled trajectories.
    #[arg(long, default_value = fissure_server::scene::DEFAULT_SCENE)]
    pub scene: String,
    /// Output folder (created; existing files in it are overwritten).
    #[arg(long, default_value = "fissure-out/demo")]
    pub out: PathBuf,
    /// Pacing of the poses: `fast` streams as fast as the server answers (the
    /// simulation runs in stepped mode, so results do not depend on speed);
    /// `realtime` sends each pose at its timestamp.
    #[arg(long, value_enum, default_value_t = Pacing::Fast)]
    pub pacing: Pacing,
    /// Hide the progress bars.
    #[arg(long)]
    pub quiet: bool,
}

/// What the demo produced.
#[derive(Debug, Clone)]
pub struct DemoReport {
    /// Output folder.
    pub out: PathBuf,
    /// Per instrument: name and its force rows.
    pub forces: Vec<(String, Vec<ForceRow>)>,
    /// Frame summaries collected by the watcher.
    pub frames: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Runs the demo.
pub async fn run(args: &DemoArgs) -> anyhow::Result<DemoReport> {
    let (scene, _) =
        Scene::load(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    let plans: Vec<(String, Trajectory)> = BUNDLED
        .iter()
        .filter(|b| b.1 == scene.name)
        .map(|b| Ok((b.2.to_owned(), Trajectory::load(b.0)?)))
        .collect::<anyhow::Result<_>>()?;
    if plans.is_empty() {
        bail!("scene {:?} has no bundled trajectories", scene.name);
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let recording = args.out.join("session.fsrec");
    let options = SimOptions {
        stepped: Some(true),
        stepped_clients: plans.len(),
        recording: Some(recording.clone()),
        max_watchers: 4,
    };
    let scene_name = scene.name.clone();
    let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
    let server = serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
    server.set_simulation(sim.clone()).await;
    let url = format!("http://{}", server.addr);

    let mut client = connect(&url).await?;
    let surface = client
        .get_surface(pb::GetSurfaceRequest {})
        .await?
        .into_inner();
    // Watcher: keeps the frame with the largest displacement and the last one.
    let frames: Arc<
        Mutex<(
            usize,
            Option<pb::DeformationFrame>,
            Option<pb::DeformationFrame>,
        )>,
    > = Arc::new(Mutex::new((0, None, None)));
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let watched = frames.clone();
    let watcher = tokio::spawn(async move {
        while let Ok(Some(f)) = watch.message().await {
            let mut w = watched.lock().expect("frames lock");
            w.0 += 1;
            let bigger =
                w.1.as_ref()
                    .is_none_or(|m| f.max_displacement_m > m.max_displacement_m);
            if bigger {
                w.1 = Some(f.clone());
            }
            w.2 = Some(f);
        }
    });

    let multi = MultiProgress::new();
    if args.quiet {
        multi.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let style = ProgressStyle::with_template("{prefix:>8} [{bar:40}] {percent:>3}% {msg}")
        .expect("valid template")
        .progress_chars("=> ");
    let mut tasks = Vec::new();
    for (instrument, trajectory) in plans {
        let bar = multi.add(ProgressBar::new(1000));
        bar.set_style(style.clone());
        bar.set_prefix(instrument.clone());
        bar.set_message(format!("{} poses", trajectory.points.len()));
        let url = url.clone();
        let pacing = args.pacing;
        tasks.push(tokio::spawn(async move {
            let mut client = connect(&url).await?;
            let rows = replay(&mut client, &instrument, None, &trajectory, pacing, |f| {
                bar.set_position((f * 1000.0) as u64)
            })
            .await?;
            bar.finish();
            anyhow::Ok((instrument, rows))
        }));
    }
    let mut forces = Vec::new();
    for t in tasks {
        forces.push(t.await??);
    }
    // Let the last frame reach the watcher, then stop.
    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    watcher.abort();
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    server.shutdown().await?;
    tokio::task::spawn_blocking({
        let sim = sim.clone();
        move || {
            sim.shutdown();
            sim.recorder().map_or(Ok(()), |r| r.finish())
        }
    })
    .await??;

    let mut files = vec![recording];
    for (name, rows) in &forces {
        let path = args.out.join(format!("forces-{name}.csv"));
        write(&path, &forces_csv(rows))?;
        files.push(path);
    }
    let (frame_count, deepest, last) = {
        let w = frames.lock().expect("frames lock");
        (w.0, w.1.clone(), w.2.clone())
    };
    for (label, frame) in [("deepest", deepest), ("final", last)] {
        if let Some(f) = frame {
            let path = args.out.join(format!("surface-{label}.obj"));
            write(&path, &surface_obj(&surface, &f))?;
            files.push(path);
        }
    }
    let summary = summary_table(&scene_name, &forces, &stats);
    let path = args.out.join("summary.txt");
    write(&path, &summary)?;
    files.push(path);
    if !args.quiet {
        println!("{summary}");
        println!("Results in {}:", args.out.display());
        for f in &files {
            println!("  {}", f.display());
        }
    }
    Ok(DemoReport {
        out: args.out.clone(),
        forces,
        frames: frame_count,
        files,
    })
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// The deformed surface of a frame as Wavefront OBJ (positions in metres).
pub fn surface_obj(surface: &pb::SurfaceMesh, frame: &pb::DeformationFrame) -> String {
    let mut s = format!(
        "# fissure surface, frame {} at t = {:.3} s; units: m\n",
        frame.frame, frame.sim_time_s
    );
    let positions: Vec<f64> = if frame.positions_m.len() == surface.rest_positions_m.len() {
        frame.positions_m.iter().map(|&v| v as f64).collect()
    } else {
        surface.rest_positions_m.clone()
    };
    for p in positions.chunks_exact(3) {
        s.push_str(&format!("v {:.7} {:.7} {:.7}\n", p[0], p[1], p[2]));
    }
    for t in surface.triangles.chunks_exact(3) {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    s
}

/// The summary printed at the end of the demo.
pub fn summary_table(scene: &str, forces: &[(String, Vec<ForceRow>)], stats: &pb::Stats) -> String {
    let mut s = format!("fissure demo — scene {scene}\n\n");
    s.push_str(&format!(
        "{:<10} {:>8} {:>11} {:>11} {:>9} {:>13} {:>13} {:>12}\n",
        "instrument",
        "samples",
        "peak |F| N",
        "mean |F| N",
        "max cont.",
        "server p50 us",
        "server p99 us",
        "rtt p99 us"
    ));
    for (name, rows) in forces {
        let mags: Vec<f64> = rows
            .iter()
            .map(|r| (r.force_n[0].powi(2) + r.force_n[1].powi(2) + r.force_n[2].powi(2)).sqrt())
            .collect();
        let in_contact: Vec<f64> = mags
            .iter()
            .zip(rows)
            .filter(|(_, r)| r.contact_count > 0)
            .map(|(m, _)| *m)
            .collect();
        let peak = mags.iter().copied().fold(0.0, f64::max);
        let mean = if in_contact.is_empty() {
            0.0
        } else {
            in_contact.iter().sum::<f64>() / in_contact.len() as f64
        };
        let mut server: Vec<f64> = rows.iter().map(|r| r.server_us).collect();
        server.sort_by(f64::total_cmp);
        let mut rtt: Vec<f64> = rows.iter().map(|r| r.rtt_us).collect();
        rtt.sort_by(f64::total_cmp);
        s.push_str(&format!(
            "{:<10} {:>8} {:>11.4} {:>11.4} {:>9} {:>13.1} {:>13.1} {:>12.1}\n",
            name,
            rows.len(),
            peak,
            mean,
            rows.iter().map(|r| r.contact_count).max().unwrap_or(0),
            percentile(&server, 0.5),
            percentile(&server, 0.99),
            percentile(&rtt, 0.99),
        ));
    }
    if let Some(step) = &stats.deformation_step {
        s.push_str(&format!(
            "\ndeformation steps: {} (p50 {:.2} ms, p99 {:.2} ms), failed: {}\n",
            stats.frames,
            step.p50_us / 1e3,
            step.p99_us / 1e3,
            stats.failed_steps
        ));
    }
    s
}
