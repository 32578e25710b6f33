//! `fissure demo`: starts the server in-process on loopback, drives every
//! instrument of the scene with its bundled trajectory at the same time, and
//! writes a results folder a person can look at:
//!
//! * `forces-<instrument>.csv` and `forces-<instrument>.png` (force versus
//!   time: |F| and its components, N);
//! * `snapshot-1-before.png`, `snapshot-2-during.png`,
//!   `snapshot-3-after.png`: the surface coloured by its non-rigid
//!   displacement (mm; `--colour-by displacement`: from rest) with
//!   the spatulas and their force arrows (for `sylvian`, seen from the left
//!   into the opened fissure); `session.gif`, the whole run;
//! * `vtu/surface-NNNNNN.vtu` with `vtu/surface.pvd` (open in ParaView; point
//!   data `displacement`, m), one per deformation frame received;
//! * `surface-deepest.obj`, `surface-final.obj`; `session.fsrec` (the
//!   recording, for `fissure report` and `fissure replay --recording`);
//!   `summary.txt` (the table printed at the end, with the rigid part of the
//!   frame of largest displacement: best-fit rotation and translation, and
//!   the largest non-rigid displacement near the instruments' tips and
//!   beyond 40 mm).

use crate::client::replay::{ForceRow, Pacing, connect, forces_csv, replay};
use crate::client::trajectory::{BUNDLED, Trajectory};
use crate::client::watch::ColourBy;
use anyhow::{Context, bail};
use fissure_engine::scene::Scene;
use fissure_engine::sim::runtime::stats::percentile;
use fissure_engine::sim::{Mode, SimOptions, Simulation};
use fissure_proto::v1 as pb;
use fissure_server::recording::ToFile;
use fissure_server::{ServeOptions, serve};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Options of the demo.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// Scene to run: an embedded name (it must have bundled trajectories),
    /// or a scene file (such as `fissure scene from-image` writes) with
    /// `--trajectory` files.
    #[arg(long, default_value = fissure_engine::scene::DEFAULT_SCENE)]
    pub scene: String,
    /// Output folder (created; existing files in it are overwritten).
    #[arg(long, default_value = "fissure-out/demo")]
    pub out: PathBuf,
    /// Pacing of the poses: `fast` streams as fast as the server answers (the
    /// simulation runs in stepped mode, so results do not depend on speed);
    /// `realtime` sends each pose at its timestamp.
    #[arg(long, value_enum, default_value_t = Pacing::Fast)]
    pub pacing: Pacing,
    /// Bundled trajectory to use (repeatable; one per instrument). By
    /// default the first bundled trajectory of each of the scene's
    /// instruments (see `fissure demo --list`). Or trajectory files: one
    /// file of several instruments (`instrument,t_s,...` CSV or JSON), or
    /// `NAME=FILE` per instrument.
    #[arg(long)]
    pub trajectory: Vec<String>,
    /// List the scenes with bundled trajectories and exit.
    #[arg(long)]
    pub list: bool,
    /// Image width, px (snapshots; the GIF is at most 640 px wide).
    #[arg(long, default_value_t = 960)]
    pub width: u32,
    /// Image height, px.
    #[arg(long, default_value_t = 640)]
    pub height: u32,
    /// Camera azimuth about +z from +x, degrees (default: per scene; for
    /// sylvian 195, from the left into the fissure).
    #[arg(long, allow_hyphen_values = true)]
    pub azimuth_deg: Option<f64>,
    /// Camera elevation above the xy plane, degrees (default: per scene).
    #[arg(long, allow_hyphen_values = true)]
    pub elevation_deg: Option<f64>,
    /// Largest number of GIF frames (the frames are thinned evenly).
    #[arg(long, default_value_t = 60)]
    pub gif_frames: usize,
    /// What the surface colour shows: `non-rigid` (the displacement left
    /// once the best-fit rigid motion of the surface is taken away) or
    /// `displacement` (from rest).
    #[arg(long, value_enum, default_value_t = ColourBy::NonRigid)]
    pub colour_by: ColourBy,
    /// Skip the pictures, the GIF and the VTU series (forces, OBJ,
    /// recording and summary only).
    #[arg(long)]
    pub no_pictures: bool,
    /// Hide the progress bars.
    #[arg(long)]
    pub quiet: bool,
}

/// The scenes with bundled trajectories, as printed by `fissure demo --list`.
pub fn list() -> String {
    let mut s = String::from("scene              instrument  bundled trajectory\n");
    for (name, scene, instrument, _) in BUNDLED {
        s.push_str(&format!("{scene:<18} {instrument:<11} {name}\n"));
    }
    s
}

/// Picks one bundled trajectory per instrument of `scene`: those named in
/// `chosen` (which must belong to the scene), then the first bundled one of
/// every other instrument.
pub fn pick_trajectories(scene: &str, chosen: &[String]) -> anyhow::Result<Vec<(String, String)>> {
    let mut plans: Vec<(String, String)> = Vec::new();
    for c in chosen {
        let Some(b) = BUNDLED.iter().find(|b| b.0 == c) else {
            bail!("--trajectory {c:?} is not a bundled trajectory (see `fissure demo --list`)");
        };
        if b.1 != scene {
            bail!(
                "--trajectory {c:?} is made for scene {:?}, not {scene:?}",
                b.1
            );
        }
        if plans.iter().any(|p| p.0 == b.2) {
            bail!("two trajectories for instrument {:?}", b.2);
        }
        plans.push((b.2.to_owned(), b.0.to_owned()));
    }
    for (name, instrument) in crate::client::trajectory::bundled_for(scene) {
        if !plans.iter().any(|p| p.0 == instrument) {
            plans.push((instrument.to_owned(), name.to_owned()));
        }
    }
    if plans.is_empty() {
        bail!(
            "scene {scene:?} has no bundled trajectories; scenes that have: {}",
            BUNDLED
                .iter()
                .map(|b| b.1)
                .fold(Vec::<&str>::new(), |mut v, s| {
                    if !v.contains(&s) {
                        v.push(s);
                    }
                    v
                })
                .join(", ")
        );
    }
    Ok(plans)
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
    /// Largest surface displacement of the run, m.
    pub max_displacement_m: f64,
    /// The rigid part of the frame with the largest displacement.
    pub rigid: Option<pb::RigidPart>,
    /// Wall-clock time of the run (server start to last file), s.
    pub elapsed_s: f64,
}

/// Runs the demo.
pub async fn run(args: &DemoArgs) -> anyhow::Result<DemoReport> {
    let started = std::time::Instant::now();
    if args.list {
        print!("{}", list());
        return Ok(DemoReport {
            out: args.out.clone(),
            forces: Vec::new(),
            frames: 0,
            files: Vec::new(),
            max_displacement_m: 0.0,
            rigid: None,
            elapsed_s: 0.0,
        });
    }
    let (scene, _) =
        Scene::load(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    let files = !args.trajectory.is_empty()
        && args
            .trajectory
            .iter()
            .all(|t| !BUNDLED.iter().any(|b| b.0 == t));
    let plans: Vec<(String, Trajectory)> = if files {
        let set = crate::client::trajectory::resolve(None, &args.trajectory)?;
        if let Some((name, _)) = set
            .iter()
            .find(|(name, _)| !scene.instruments.iter().any(|i| &i.name == name))
        {
            bail!(
                "--trajectory: instrument {name:?} is not in scene {:?} (it has {})",
                scene.name,
                scene
                    .instruments
                    .iter()
                    .map(|i| i.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        set
    } else {
        pick_trajectories(&scene.name, &args.trajectory)?
            .into_iter()
            .map(|(instrument, name)| Ok((instrument, Trajectory::load(&name)?)))
            .collect::<anyhow::Result<_>>()?
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let recording = args.out.join("session.fsrec");
    let options = SimOptions {
        mode: Some(Mode::Stepped {
            clients: plans.len(),
        }),
        recording: Some(ToFile::open_at(&recording)),
        max_watchers: 4,
        ..SimOptions::default()
    };
    let scene_name = scene.name.clone();
    let safe_force_n = scene.loops.safe_force_n;
    let sim = tokio::task::spawn_blocking(move || Simulation::start(scene, options)).await??;
    let server = serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
    server.set_simulation(sim.clone()).await;
    let url = format!("http://{}", server.addr);

    let mut client = connect(&url).await?;
    let surface = client
        .get_surface(pb::GetSurfaceRequest {})
        .await?
        .into_inner();
    let description = client.get_scene(pb::GetSceneRequest {}).await?.into_inner();
    // Watcher: keeps every frame it receives (latest-wins: it may skip some).
    let frames: Arc<Mutex<Vec<pb::DeformationFrame>>> = Arc::new(Mutex::new(Vec::new()));
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let watched = frames.clone();
    let watcher = tokio::spawn(async move {
        while let Ok(Some(f)) = watch.message().await {
            watched.lock().expect("frames lock").push(f);
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

    let assessed = crate::client::report::report(&recording, safe_force_n)
        .with_context(|| format!("assessing {}", recording.display()))?;
    let mut files = vec![recording.clone()];
    for (name, rows) in &forces {
        let path = args.out.join(format!("forces-{name}.csv"));
        write(&path, &forces_csv(rows))?;
        files.push(path);
    }
    let frames = std::mem::take(&mut *frames.lock().expect("frames lock"));
    let frame_count = frames.len();
    let frames_timings: Vec<pb::StepTimings> = frames.iter().filter_map(|f| f.timings).collect();
    let deepest = frames
        .iter()
        .max_by(|a, b| a.max_displacement_m.total_cmp(&b.max_displacement_m));
    let max_displacement_m = deepest.map_or(0.0, |f| f.max_displacement_m);
    let rigid = deepest.and_then(|f| f.rigid.as_ref().cloned());
    let motion = deepest.and_then(crate::client::report::MotionReport::of);
    for (label, frame) in [("deepest", deepest), ("final", frames.last())] {
        if let Some(f) = frame {
            let path = args.out.join(format!("surface-{label}.obj"));
            write(&path, &surface_obj(&surface, f))?;
            files.push(path);
        }
    }
    if !args.no_pictures && !frames.is_empty() {
        let pictures = Pictures {
            out: args.out.clone(),
            width: args.width,
            height: args.height,
            gif_frames: args.gif_frames,
            quiet: args.quiet,
            azimuth_deg: args.azimuth_deg,
            elevation_deg: args.elevation_deg,
            colour_by: args.colour_by,
        };
        let (description, surface) = (description.clone(), surface.clone());
        let forces = forces.clone();
        files.extend(
            tokio::task::spawn_blocking(move || {
                pictures.write(&description, &surface, &frames, &forces)
            })
            .await??,
        );
        let page = args.out.join("report.html");
        crate::client::report::html::write(&page, &assessed, "session.fsrec", None)?;
        files.push(page);
    }
    let mut summary = summary_table(&scene_name, &forces, &stats);
    summary.push_str(&format!(
        "largest surface displacement: {:.2} mm; deformation frames received: {frame_count}\n",
        max_displacement_m * 1e3
    ));
    if let Some(m) = &motion {
        summary.push_str(&m.lines());
    }
    summary.push_str(&crate::client::report::assessment_lines(
        &assessed.assessment,
    ));
    summary.push_str(&assess_cost_line(&frames_timings, &stats));
    let path = args.out.join("summary.txt");
    write(&path, &summary)?;
    files.push(path);
    let elapsed_s = started.elapsed().as_secs_f64();
    if !args.quiet {
        println!("{summary}");
        println!("Results in {} ({elapsed_s:.1} s):", args.out.display());
        print!("{}", describe_files(&args.out, &files));
    }
    Ok(DemoReport {
        out: args.out.clone(),
        forces,
        frames: frame_count,
        files,
        max_displacement_m,
        rigid,
        elapsed_s,
    })
}

/// What the injury measures cost: their p50 per step beside the server's
/// deformation step p50 (the same steps, one run).
fn assess_cost_line(timings: &[pb::StepTimings], stats: &pb::Stats) -> String {
    let mut us: Vec<f64> = timings
        .iter()
        .skip(1)
        .map(|t| t.assess_us)
        .filter(|&t| t > 0.0)
        .collect();
    let Some(step) = stats.deformation_step.as_ref().filter(|s| s.p50_us > 0.0) else {
        return String::new();
    };
    if us.is_empty() {
        return String::new();
    }
    us.sort_by(f64::total_cmp);
    let p50 = percentile(&us, 0.5);
    format!(
        "injury measures (pressure, strain): p50 {:.3} ms a step, {:.1} % of the step's p50\n",
        p50 / 1e3,
        100.0 * p50 / step.p50_us
    )
}

/// The list of results printed at the end: one line per kind of file, the
/// VTU series as one line.
fn describe_files(out: &Path, files: &[PathBuf]) -> String {
    let mut s = String::new();
    let mut vtu = 0;
    for f in files {
        let name = f.strip_prefix(out).unwrap_or(f).display().to_string();
        let what = match f.extension().and_then(|e| e.to_str()).unwrap_or("") {
            "vtu" => {
                vtu += 1;
                continue;
            }
            "pvd" => "VTU series index (open in ParaView)",
            "png" if name.starts_with("snapshot") => "snapshot",
            "png" => "force versus time",
            "gif" => "animation of the session",
            "csv" => "force samples",
            "obj" => "deformed surface",
            "fsrec" => "session recording (fissure report / replay --recording)",
            "txt" => "summary table",
            "html" => "assessment page: scores, plots, the worst strain (open in a browser)",
            _ => "",
        };
        s.push_str(&format!("  {:<34} {what}\n", name));
    }
    if vtu > 0 {
        s.push_str(&format!(
            "  {:<34} {vtu} surface frames with point data `displacement` (m)\n",
            "vtu/surface-*.vtu"
        ));
    }
    s
}

/// The pictures and the VTU series of a demo run.
struct Pictures {
    out: PathBuf,
    width: u32,
    height: u32,
    gif_frames: usize,
    quiet: bool,
    azimuth_deg: Option<f64>,
    elevation_deg: Option<f64>,
    colour_by: ColourBy,
}

impl Pictures {
    /// Writes the VTU series, the snapshots, the force plots and the GIF;
    /// returns the files written.
    ///
    /// The frames go through the same [`FrameSink`]s as `fissure watch`'s.
    /// The demo has the whole run before it writes, so a first pass makes
    /// the choices that need it (one colour scale for the run, the "during"
    /// frame, the GIF's stride), then a second pushes every frame through
    /// the sinks.
    fn write(
        &self,
        scene: &pb::SceneDescription,
        surface: &pb::SurfaceMesh,
        frames: &[pb::DeformationFrame],
        forces: &[(String, Vec<ForceRow>)],
    ) -> anyhow::Result<Vec<PathBuf>> {
        use crate::client::render::plot::{InstrumentForces, force_plot, nice_range};
        use crate::client::watch::{
            FrameRenderer, FrameSink, GifBuffer, GifSink, PngPick, PngSink, SessionView, Snapshot,
            VtuSink,
        };
        let Some(last) = frames.len().checked_sub(1) else {
            return Ok(Vec::new());
        };
        let bar = ProgressBar::new((frames.len() + forces.len() + 1) as u64);
        if self.quiet {
            bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        bar.set_style(
            ProgressStyle::with_template("{prefix:>8} [{bar:40}] {percent:>3}% {msg}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        bar.set_prefix("pictures");
        let mut view = SessionView::new(scene, surface);
        view.colour_by = self.colour_by;
        if let Some(a) = self.azimuth_deg {
            view.camera.azimuth_deg = a;
        }
        if let Some(e) = self.elevation_deg {
            view.camera.elevation_deg = e;
        }
        // First pass, the choices over the whole run: one colour scale for
        // every picture (the run's largest value of what the colour shows);
        // the "during" snapshot, the first frame at half that peak; the
        // GIF's stride, which thins the frames evenly to `--gif-frames`.
        let peak_mm = frames
            .iter()
            .map(|f| self.colour_by.peak_mm(f))
            .fold(0.0, f64::max);
        let range_mm = nice_range(0.0, peak_mm.max(0.1), 5).1;
        let during = frames
            .iter()
            .position(|f| self.colour_by.peak_mm(f) >= 0.5 * peak_mm)
            .unwrap_or(frames.len() / 2);
        let stride = frames.len().div_ceil(self.gif_frames.max(2)).max(1);
        // Second pass: every frame through the sinks. The VTU series, one
        // per frame received, in `vtu/`; the snapshots before, during and
        // after; the animation at most 640 px wide.
        let dir = self.out.join("vtu");
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let snapshot = |index: usize, file: &str, label: &str| Snapshot {
            index,
            file: file.into(),
            label: label.into(),
        };
        let (gw, gh) = if self.width > 640 {
            (640, (self.height * 640 / self.width).max(240))
        } else {
            (self.width, self.height)
        };
        let mut sinks: [Box<dyn FrameSink>; 3] = [
            Box::new(VtuSink::new(&dir, "surface", true)),
            Box::new(PngSink::new(
                &self.out,
                FrameRenderer::new(self.width, self.height)?,
                PngPick::Chosen(vec![
                    snapshot(0, "snapshot-1-before.png", "before"),
                    snapshot(during, "snapshot-2-during.png", "during"),
                    snapshot(last, "snapshot-3-after.png", "after"),
                ]),
            )),
            Box::new(GifSink::new(
                self.out.join("session.gif"),
                FrameRenderer::new(gw, gh)?,
                GifBuffer::every(stride as u64, frames.len() as u64),
            )),
        ];
        bar.set_message("VTU series, snapshots, animation frames");
        for f in frames {
            for sink in &mut sinks {
                sink.frame(&view, f, range_mm)?;
            }
            bar.inc(1);
        }
        let [series, snapshots, animation] = sinks;
        let mut files = series.finish(&view)?;
        files.extend(snapshots.finish(&view)?);
        // Force plots (not frames: the demo's own).
        bar.set_message("force plots");
        for (name, rows) in forces {
            let ins = InstrumentForces {
                name: name.clone(),
                time: rows.iter().map(|r| r.t_s).collect(),
                force: rows.iter().map(|r| r.force_n).collect(),
            };
            let path = self.out.join(format!("forces-{name}.png"));
            force_plot(
                &format!("{} \u{2014} force on the {name} spatula", scene.name),
                &[ins],
                true,
                None,
            )
            .save_png(&path)?;
            files.push(path);
            bar.inc(1);
        }
        bar.set_message("animation");
        files.extend(animation.finish(&view)?);
        bar.inc(1);
        bar.finish_and_clear();
        Ok(files)
    }
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
