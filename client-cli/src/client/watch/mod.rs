//! `fissure watch`: subscribes to a server's deformation frames and writes
//! what a person opens afterwards:
//!
//! * a VTU time series of the boundary surface (`surface-NNNNNN.vtu`, point
//!   data `displacement` in m) with its ParaView index `surface.pvd`
//!   (`timestep` = the frame's simulation time, s);
//! * PNG images of the deformed surface coloured by displacement magnitude
//!   (mm), with the spatulas as plates and their reaction forces as arrows
//!   (`frame-NNNNNN.png`);
//! * an animated GIF of the session (`session.gif`);
//! * on the standard output, a line when a measure of the assessment (the
//!   retraction pressure, the tissue's strain; [`crate::client::report::assess`])
//!   first reaches its warning level and its failing level, and the scores
//!   of the frames received at the end.
//!
//! The files are completed (the `.pvd` index, the last PNG, the GIF) however
//! the stream ends: the server shutting down, the connection failing,
//! `--max-frames`, `--duration-s` or Ctrl-C. A task reads the stream as fast
//! as it comes and keeps only the newest frame; the writer takes the newest
//! each time it is ready, so a watcher slower than the simulation stays
//! current and says how many frames it skipped ([`WatchReport::skipped`])
//! instead of falling behind.
//!
//! The three kinds of file are [`FrameSink`]s ([`sink`]), the outputs this
//! command shares with `fissure demo`: each kept frame goes through them in
//! turn, with the colour scale of the moment.
//!
//! The pictures are drawn by [`crate::client::render::frame::FrameRenderer`], the
//! one frame renderer of the demo, the watcher and the tests;
//! [`SessionView`] holds what a session's pictures need (rest surface,
//! instruments, a camera per scene) and turns a frame into what it draws.
//!
//! Colours: undisplaced tissue is a light pink ([`TISSUE_MAP`] at 0), deeper
//! displacement blends through salmon and orange-red to dark crimson, so
//! that the tissue reads as tissue and the deformation stands out.

mod gif;
pub mod sink;
pub(crate) mod view;
mod vtu;

pub use crate::client::render::frame::{
    ARROWS, CameraPreset, Caption, FrameRenderer, STEEL, STEEL_CONTACT, TISSUE_MAP, tissue_colour,
};
pub use gif::{GifBuffer, gif_delay_cs};
pub use sink::{FrameSink, GifSink, PngPick, PngSink, Snapshot, VtuSink};
pub use view::{ColourBy, SessionView, caption_of, plate, pose_of};
pub use vtu::{VtuSeries, pvd};

use crate::client::replay::connect;
use anyhow::Context;
use fissure_proto::v1 as pb;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Options of `fissure watch`.
#[derive(Debug, Clone, clap::Args)]
pub struct WatchArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    pub server: String,
    /// Output folder (created; files in it are overwritten).
    #[arg(long, default_value = "fissure-out/watch")]
    pub out: PathBuf,
    /// Keep every Nth frame received (1 = all). Frames are latest-wins: a
    /// slow watcher already skips frames, this thins them further.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub every: u64,
    /// Stop after this many kept frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Stop after this long, s (wall clock). Without a limit, watch until
    /// the server ends the stream (or shuts down), the connection fails, or
    /// Ctrl-C; the files are completed in every case.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Image width, px (at least 320).
    #[arg(long, default_value_t = 960)]
    pub width: u32,
    /// Image height, px (at least 240).
    #[arg(long, default_value_t = 640)]
    pub height: u32,
    /// Write a PNG image of every kept frame (else only the first and last).
    #[arg(long)]
    pub png_all: bool,
    /// Largest number of GIF frames; above it the kept frames are thinned
    /// evenly (every 2nd, 4th, ...).
    #[arg(long, default_value_t = 150)]
    pub gif_frames: usize,
    /// Skip the VTU series.
    #[arg(long)]
    pub no_vtu: bool,
    /// Colour scale maximum, mm of displacement; by default the largest
    /// displacement seen so far (the scale then grows during the session).
    #[arg(long)]
    pub range_mm: Option<f64>,
    /// Camera azimuth about +z from +x, degrees (default: per scene).
    #[arg(long, allow_hyphen_values = true)]
    pub azimuth_deg: Option<f64>,
    /// Camera elevation above the xy plane, degrees (default: per scene).
    #[arg(long, allow_hyphen_values = true)]
    pub elevation_deg: Option<f64>,
    /// What the surface colour shows: `non-rigid` (the displacement left
    /// once the best-fit rigid motion of the surface is taken away) or
    /// `displacement` (from rest).
    #[arg(long, value_enum, default_value_t = ColourBy::NonRigid)]
    pub colour_by: ColourBy,
}

/// How a watch ended.
#[derive(Debug, Clone, PartialEq)]
pub enum WatchEnd {
    /// `--max-frames` frames were kept.
    MaxFrames,
    /// `--duration-s` passed.
    Duration,
    /// Ctrl-C.
    Interrupted,
    /// The server ended the stream.
    ServerEnded,
    /// The server shut down (`UNAVAILABLE`, "the server is shutting down").
    ServerShutDown,
    /// The stream failed (connection lost, another status): the message.
    Failed(String),
}

impl std::fmt::Display for WatchEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::MaxFrames => write!(f, "--max-frames reached"),
            Self::Duration => write!(f, "--duration-s passed"),
            Self::Interrupted => write!(f, "interrupted"),
            Self::ServerEnded => write!(f, "the server ended the stream"),
            Self::ServerShutDown => write!(f, "the server shut down"),
            Self::Failed(why) => write!(f, "the stream failed: {why}"),
        }
    }
}

/// What `fissure watch` wrote.
#[derive(Debug, Clone)]
pub struct WatchReport {
    /// Frames taken from the stream (the newest each time the writer was
    /// ready).
    pub received: usize,
    /// Frames kept (every Nth of those received).
    pub kept: usize,
    /// Frame numbers between the first and the last frame received that
    /// were never received: skipped by the server (latest-wins) or replaced
    /// by a newer one before the writer was ready.
    pub skipped: u64,
    /// Numbers of the first and the last frame received.
    pub frames: Option<(u64, u64)>,
    /// Why the watch ended.
    pub ended: WatchEnd,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Reads `stream` into a latest-wins slot until it ends; returns how.
async fn receive(
    mut stream: tonic::Streaming<pb::DeformationFrame>,
    slot: tokio::sync::watch::Sender<Option<pb::DeformationFrame>>,
) -> WatchEnd {
    loop {
        match stream.message().await {
            Ok(Some(f)) => {
                slot.send_replace(Some(f));
            }
            Ok(None) => return WatchEnd::ServerEnded,
            Err(status)
                if status.code() == tonic::Code::Unavailable
                    && status.message().contains("shutting down") =>
            {
                return WatchEnd::ServerShutDown;
            }
            Err(status) => return WatchEnd::Failed(status.to_string()),
        }
    }
}

/// Runs `fissure watch`.
pub async fn run(args: &WatchArgs) -> anyhow::Result<WatchReport> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut client = connect(&args.server).await?;
    let scene = client
        .get_scene(pb::GetSceneRequest {})
        .await
        .context("GetScene")?
        .into_inner();
    let surface = client
        .get_surface(pb::GetSurfaceRequest {})
        .await
        .context("GetSurface")?
        .into_inner();
    let mut view = SessionView::new(&scene, &surface);
    view.colour_by = args.colour_by;
    if let Some(a) = args.azimuth_deg {
        view.camera.azimuth_deg = a;
    }
    if let Some(e) = args.elevation_deg {
        view.camera.elevation_deg = e;
    }
    let stream = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await
        .context("Watch")?
        .into_inner();
    // The files, in the order they are listed: the pictures, the VTU
    // series' index, the GIF.
    let mut sinks: Vec<Box<dyn FrameSink>> = vec![Box::new(PngSink::new(
        &args.out,
        FrameRenderer::new(args.width, args.height)?,
        if args.png_all {
            PngPick::All
        } else {
            PngPick::FirstAndLast
        },
    ))];
    if !args.no_vtu {
        sinks.push(Box::new(VtuSink::new(&args.out, "surface", false)));
    }
    sinks.push(Box::new(GifSink::new(
        args.out.join("session.gif"),
        FrameRenderer::new(args.width.min(640), args.height.min(427))?,
        GifBuffer::new(args.gif_frames),
    )));
    let (slot, mut latest) = tokio::sync::watch::channel(None);
    let receiver = tokio::spawn(receive(stream, slot));
    let mut report = WatchReport {
        received: 0,
        kept: 0,
        skipped: 0,
        frames: None,
        ended: WatchEnd::ServerEnded,
        files: Vec::new(),
    };
    let (thresholds, _) = crate::client::report::assess::thresholds(Some(&scene));
    let mut live = crate::client::report::assess::LiveAlerts::new(thresholds);
    let mut assessor = crate::client::report::assess::Assessor::new(thresholds, true);
    let mut max_mm: f64 = 0.0;
    let deadline = args
        .duration_s
        .map(|d| Instant::now() + Duration::from_secs_f64(d.max(0.0)));
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    let mut ended = None;
    while ended.is_none() {
        let timeout = async {
            match deadline {
                Some(d) => tokio::time::sleep_until(d.into()).await,
                None => std::future::pending().await,
            }
        };
        let frame = tokio::select! {
            changed = latest.changed() => match changed {
                Ok(()) => latest.borrow_and_update().clone(),
                // The stream ended and its last frame was taken.
                Err(_) => break,
            },
            _ = timeout => { ended = Some(WatchEnd::Duration); None }
            _ = &mut ctrl_c => { ended = Some(WatchEnd::Interrupted); None }
        };
        let Some(frame) = frame else { continue };
        // Every frame received is assessed (the engine's sums make a
        // skipped frame lose nothing but its own peak).
        for alert in live.frame(&frame) {
            println!("{}", alert.line());
        }
        assessor.frame(&frame);
        report.received += 1;
        report.frames = Some(match report.frames {
            None => (frame.frame, frame.frame),
            Some((first, prev)) => {
                report.skipped += frame.frame.saturating_sub(prev + 1);
                (first, frame.frame.max(prev))
            }
        });
        if (report.received as u64 - 1) % args.every != 0 {
            continue;
        }
        report.kept += 1;
        max_mm = max_mm.max(args.colour_by.peak_mm(&frame));
        let range_mm = args.range_mm.unwrap_or(max_mm.max(0.1));
        for sink in &mut sinks {
            sink.frame(&view, &frame, range_mm)?;
        }
        if args.max_frames.is_some_and(|m| report.kept >= m) {
            ended = Some(WatchEnd::MaxFrames);
        }
    }
    report.ended = match ended {
        Some(e) => {
            receiver.abort();
            e
        }
        None => receiver
            .await
            .unwrap_or_else(|e| WatchEnd::Failed(e.to_string())),
    };
    for sink in sinks {
        report.files.extend(sink.finish(&view)?);
    }
    if report.received > 0 {
        print!(
            "{}",
            crate::client::report::assessment_lines(&assessor.finish(&[], f64::INFINITY))
        );
    }
    let span = report
        .frames
        .map_or(String::new(), |(a, b)| format!(" (frames {a}..{b})"));
    let skipped = if report.skipped > 0 {
        " (latest-wins: frames came faster than this watcher wrote them)"
    } else {
        ""
    };
    println!(
        "{}: {} frames received{span}, {} kept, {} skipped{skipped}; {} VTU files (+ surface.pvd) in {}",
        report.ended,
        report.received,
        report.kept,
        report.skipped,
        if args.no_vtu { 0 } else { report.kept },
        args.out.display()
    );
    for f in &report.files {
        println!("  {}", f.display());
    }
    if let WatchEnd::Failed(why) = &report.ended {
        anyhow::bail!(
            "the frame stream failed: {why} (the files written so far are completed, {} of them)",
            report.files.len()
        );
    }
    Ok(report)
}
