//! `fissure watch` against an in-process server: the files are completed
//! when the server shuts down and when the connection fails, the VTU files
//! it writes are read back as surfaces, and a watcher slower than a fast
//! stepped replay stays current and counts the frames it skipped.

use crate::reliability_common::{FLAT_DOWN, HANDLE_Y, LEFT_X, TOUCH_Z};
use fissure_cli::client::watch::{WatchArgs, WatchEnd, run};
use fissure_cli::lab::mesh::{InspectOptions, convert, inspect};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use std::path::Path;
use std::time::Duration;

fn args(server: &str, out: &Path) -> WatchArgs {
    WatchArgs {
        server: server.to_owned(),
        out: out.to_owned(),
        every: 1,
        max_frames: None,
        duration_s: None,
        width: 320,
        height: 240,
        png_all: false,
        gif_frames: 20,
        no_vtu: false,
        range_mm: None,
        azimuth_deg: None,
        elevation_deg: None,
        colour_by: fissure_cli::client::watch::ColourBy::NonRigid,
    }
}

/// Presses `left` into the cube over `n` poses, 1 ms apart in time.
async fn press(haptic: &mut Haptic, n: u64, pace: Option<Duration>) -> anyhow::Result<()> {
    for k in 0..n {
        let z = TOUCH_Z + 0.0005 - 0.0025 * (k as f64 / n as f64);
        haptic
            .send(pose(
                k as f64 * 1e-3,
                k + 1,
                [LEFT_X, HANDLE_Y, z],
                FLAT_DOWN,
            ))
            .await?;
        if let Some(p) = pace {
            tokio::time::sleep(p).await;
        }
    }
    Ok(())
}

/// The server shuts down while `fissure watch` runs (the stream ends with
/// UNAVAILABLE, "the server is shutting down"): the watch returns normally,
/// says so, and has written the `.pvd` index of every VTU it wrote, the
/// first and the last PNG and the GIF.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watch_completes_its_files_when_the_server_shuts_down() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let dir = tempfile::tempdir()?;
    let a = args(&server.url, dir.path());
    let watch = tokio::spawn(async move { run(&a).await });
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    press(&mut haptic, 400, Some(Duration::from_millis(1))).await?;
    haptic.close().await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    server.stop().await?;
    let report = tokio::time::timeout(Duration::from_secs(30), watch).await???;
    assert_eq!(report.ended, WatchEnd::ServerShutDown);
    assert!(report.kept >= 3, "{report:?}");
    let names: Vec<String> = report
        .files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    let (first, last) = report.frames.expect("frames");
    for want in [
        format!("frame-{first:06}.png"),
        format!("frame-{last:06}.png"),
        "surface.pvd".into(),
        "session.gif".into(),
    ] {
        assert!(names.contains(&want), "{want} not in {names:?}");
        assert!(dir.path().join(&want).is_file(), "{want}");
    }
    let pvd = std::fs::read_to_string(dir.path().join("surface.pvd"))?;
    let listed: Vec<&str> = pvd
        .lines()
        .filter_map(|l| l.split("file=\"").nth(1))
        .map(|rest| rest.trim_end_matches("\"/>"))
        .collect();
    assert_eq!(listed.len(), report.kept, "{pvd}");
    assert!(listed.iter().all(|f| dir.path().join(f).is_file()));
    // What it wrote is a surface to the mesh tools: inspected as one, with
    // no problem (the cube's closed boundary), and converted to STL.
    let last_vtu = dir.path().join(listed.last().expect("a VTU"));
    let r = inspect(&last_vtu, &InspectOptions::default())?;
    assert_eq!(
        (r.kind, r.tets, r.problems_found),
        ("surface", 0, 0),
        "{r:?}"
    );
    assert!(r.surface_triangles > 0 && r.volume_m3 > 0.0, "{r:?}");
    let stl = dir.path().join("last.stl");
    let s = convert(&last_vtu, &stl, 1.0)?;
    assert!(
        s.ends_with(&format!("{} triangles", r.surface_triangles)),
        "{s}"
    );
    Ok(())
}

/// A TCP relay from a local port to `to` whose connections all drop when
/// the returned sender is dropped (a connection lost mid-stream).
async fn relay(
    to: std::net::SocketAddr,
) -> anyhow::Result<(String, tokio::sync::oneshot::Sender<()>)> {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let url = format!("http://{}", listener.local_addr()?);
    let (cut, cut_rx) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(async move {
        let mut links = tokio::task::JoinSet::new();
        let accept = async {
            while let Ok((mut client, _)) = listener.accept().await {
                links.spawn(async move {
                    let mut server = tokio::net::TcpStream::connect(to).await?;
                    tokio::io::copy_bidirectional(&mut client, &mut server).await
                });
            }
        };
        tokio::select! {
            _ = accept => {}
            _ = cut_rx => {}
        }
        // Dropping the set aborts every link: both sockets close.
    });
    Ok((url, cut))
}

/// The connection fails while `fissure watch` runs (its TCP link to the
/// server is cut, the server still up): the watch fails, saying the stream
/// failed (the command exits 1), after it has completed its files: the
/// `.pvd` index of every VTU written, the first and the last PNG, the GIF.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watch_completes_its_files_when_the_connection_fails() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let (url, cut) = relay(server.addr).await?;
    let dir = tempfile::tempdir()?;
    let a = args(&url, dir.path());
    let watch = tokio::spawn(async move { run(&a).await });
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    press(&mut haptic, 400, Some(Duration::from_millis(1))).await?;
    haptic.close().await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    drop(cut);
    let err = tokio::time::timeout(Duration::from_secs(30), watch)
        .await??
        .expect_err("a failed stream is an error");
    let err = format!("{err:#}");
    assert!(
        err.contains("the frame stream failed") && err.contains("completed"),
        "{err}"
    );
    let pvd = std::fs::read_to_string(dir.path().join("surface.pvd"))?;
    let listed: Vec<&str> = pvd
        .lines()
        .filter_map(|l| l.split("file=\"").nth(1))
        .map(|rest| rest.trim_end_matches("\"/>"))
        .collect();
    let vtus = std::fs::read_dir(dir.path())?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".vtu"))
        .count();
    assert!(listed.len() >= 3, "{pvd}");
    assert_eq!(listed.len(), vtus, "the index lists every VTU written");
    let pngs = std::fs::read_dir(dir.path())?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".png"))
        .count();
    assert_eq!(pngs, 2, "the first and the last frame");
    assert!(dir.path().join("session.gif").is_file());
    server.stop().await
}

/// A fast stepped replay (poses sent as fast as answered) makes frames
/// faster than a watcher that writes a full-size PNG of every frame can
/// draw: the watcher skips frames, counts them (frame numbers never
/// received between its first and last), and still ends on the replay's
/// final frame.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_watcher_stays_current_and_counts_the_frames_it_skipped() -> anyhow::Result<()> {
    let server = TestServer::start(
        "cube",
        SimOptions {
            mode: Some(Mode::Stepped { clients: 1 }),
            ..Default::default()
        },
        ServeOptions::default(),
    )
    .await?;
    let dir = tempfile::tempdir()?;
    let mut a = args(&server.url, dir.path());
    a.png_all = true;
    a.width = 1280;
    a.height = 960;
    let watch = tokio::spawn(async move { run(&a).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    press(&mut haptic, 3_000, None).await?;
    let final_frame = server.sim.snapshot().frame;
    haptic.close().await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    server.stop().await?;
    let report = tokio::time::timeout(Duration::from_secs(60), watch).await???;
    let (first, last) = report.frames.expect("frames");
    assert!(
        last >= final_frame,
        "last {last}, replay ended at {final_frame}"
    );
    assert!(report.skipped > 0, "{report:?}");
    assert_eq!(
        report.received as u64 + report.skipped,
        last - first + 1,
        "{report:?}"
    );
    Ok(())
}
