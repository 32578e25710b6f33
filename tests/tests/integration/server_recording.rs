//! Session recordings end to end: a stepped two-instrument session on the
//! `cube` scene is recorded, read back entry by entry, summarised by
//! `fissure report`, and replayed with `fissure replay --recording` against a
//! fresh server, which gives the same forces.

use fissure_cli::client::replay::{ForceRow, Pacing, connect, replay};
use fissure_cli::client::trajectory::Trajectory;
use fissure_engine::sim::{Mode, SimOptions};
use fissure_proto::recording;
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_server::recording::ToFile;
use fissure_tests::TestServer;
use std::collections::BTreeMap;
use std::path::Path;

fn stepped(clients: usize, recording: Option<&Path>) -> SimOptions {
    SimOptions {
        mode: Some(Mode::Stepped { clients }),
        recording: recording.map(ToFile::open_at),
        ..SimOptions::default()
    }
}

/// Streams every `(instrument, trajectory)` at once to a stepped `cube`
/// server; returns the force rows per instrument and the server's stats at
/// the end of the session.
async fn run(
    options: SimOptions,
    plans: &[(String, Trajectory)],
) -> anyhow::Result<(BTreeMap<String, Vec<ForceRow>>, pb::Stats)> {
    let server = TestServer::start("cube", options, ServeOptions::default()).await?;
    let mut tasks = Vec::new();
    for (name, trajectory) in plans {
        let (url, name, trajectory) = (server.url.clone(), name.clone(), trajectory.clone());
        tasks.push(tokio::spawn(async move {
            let mut client = connect(&url).await?;
            let rows = replay(&mut client, &name, None, &trajectory, Pacing::Fast, |_| {}).await?;
            anyhow::Ok((name, rows))
        }));
    }
    let mut out = BTreeMap::new();
    for t in tasks {
        let (name, rows) = t.await??;
        out.insert(name, rows);
    }
    let stats = server
        .client()
        .await?
        .get_stats(pb::GetStatsRequest {})
        .await?
        .into_inner();
    let sim = server.sim.clone();
    server.stop().await?;
    tokio::task::spawn_blocking(move || sim.recorder().map_or(Ok(()), |r| r.finish())).await??;
    Ok((out, stats))
}

fn magnitude(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Record, read back, report, replay.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recording_round_trip_report_and_replay() -> anyhow::Result<()> {
    let plans = vec![
        ("left".to_owned(), Trajectory::load("cube-press-left")?),
        ("right".to_owned(), Trajectory::load("cube-press-right")?),
    ];
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("session.fsrec");
    let (live, stats) = run(stepped(2, Some(&path)), &plans).await?;
    // GetStats: every sample answered, nothing dropped by the recorder.
    let answered: usize = live.values().map(Vec::len).sum();
    assert_eq!(stats.force_samples, answered as u64);
    assert_eq!(stats.recording_lost, 0, "{stats:?}");

    // 1. Read back: header first, then every accepted pose and every force
    // sample of each instrument in order, and the frame summaries.
    let (entries, truncated) = recording::read(&path)?;
    assert!(!truncated);
    let Some(pb::recording_entry::Entry::Header(header)) = &entries[0].entry else {
        panic!("the first entry is not a header: {:?}", entries[0]);
    };
    assert_eq!(header.version, 1);
    let scene = header.scene.as_ref().expect("scene");
    assert_eq!(scene.name, "cube");
    assert!(scene.loops.as_ref().expect("loops").stepped);
    let mut poses: BTreeMap<String, Vec<pb::PoseSample>> = BTreeMap::new();
    let mut forces: BTreeMap<String, Vec<pb::ForceSample>> = BTreeMap::new();
    let mut frames = Vec::new();
    for e in &entries[1..] {
        match e.entry.clone().expect("entry") {
            pb::recording_entry::Entry::Header(_) => panic!("a second header"),
            pb::recording_entry::Entry::Pose(p) => poses
                .entry(p.instrument)
                .or_default()
                .push(p.pose.expect("pose")),
            pb::recording_entry::Entry::Force(f) => forces
                .entry(f.instrument)
                .or_default()
                .push(f.sample.expect("sample")),
            pb::recording_entry::Entry::Frame(f) => frames.push(f),
            pb::recording_entry::Entry::Gap(g) => panic!("entries lost: {g:?}"),
        }
    }
    for (name, trajectory) in &plans {
        let recorded = &poses[name];
        assert_eq!(recorded.len(), trajectory.points.len(), "{name} poses");
        for (i, (p, w)) in recorded.iter().zip(&trajectory.points).enumerate() {
            let pos = p.position_m.expect("position");
            let q = p.orientation.expect("orientation");
            assert_eq!(p.sequence, i as u64 + 1, "{name}");
            assert_eq!(
                (p.t_s, pos.x, pos.y, pos.z, q.w, q.x, q.y, q.z),
                (w.t_s, w.x_m, w.y_m, w.z_m, w.qw, w.qx, w.qy, w.qz),
                "{name} pose {i}"
            );
        }
        // The recorded samples are the ones the client received, in order.
        let rows = &live[name];
        let recorded = &forces[name];
        assert_eq!(recorded.len(), rows.len(), "{name} samples");
        for (s, r) in recorded.iter().zip(rows) {
            let f = s.force_n.expect("force");
            assert_eq!(s.sequence, r.sequence, "{name}");
            assert_eq!([f.x, f.y, f.z], r.force_n, "{name} sample {}", r.sequence);
            assert_eq!(s.server_compute_us, r.server_us);
            assert_eq!(s.model_frame, r.model_frame);
        }
    }
    // The rest frame 0 the server starts from, then one frame per
    // deformation interval of pose time, numbered 1, 2, ...
    let dt = scene.loops.as_ref().expect("loops").deformation_interval_s;
    let duration = plans[0].1.points.last().expect("points").t_s;
    assert!(
        frames.len() as f64 >= duration / dt - 1.0,
        "{} frames for {duration} s",
        frames.len()
    );
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.frame, i as u64);
        assert!(f.positions_m.is_empty(), "frames are recorded as summaries");
        assert_eq!(f.instruments.len(), 2);
    }
    let failed = frames.iter().filter(|f| !f.solver_error.is_empty()).count();
    assert!(
        frames.iter().any(|f| f.max_displacement_m > 1e-3),
        "the recorded frames never show the push"
    );

    // 2. `fissure report`: peak force, path length and duration against the
    // same quantities computed here from the trajectories and the live rows.
    let threshold = 0.05;
    let report = fissure_cli::client::report::report(&path, threshold)?;
    assert_eq!(report.scene, "cube");
    assert_eq!(report.frames, frames.len());
    assert_eq!(report.failed_frames, failed);
    assert!(!report.truncated);
    assert_eq!(report.instruments.len(), 2);
    for (name, trajectory) in &plans {
        let r = report
            .instruments
            .iter()
            .find(|r| &r.instrument == name)
            .expect("instrument in report");
        let pts = &trajectory.points;
        let path_length: f64 = pts
            .windows(2)
            .map(|w| {
                magnitude([
                    w[1].x_m - w[0].x_m,
                    w[1].y_m - w[0].y_m,
                    w[1].z_m - w[0].z_m,
                ])
            })
            .sum();
        let peak = live[name]
            .iter()
            .map(|r| magnitude(r.force_n))
            .fold(0.0, f64::max);
        let above: f64 = live[name]
            .windows(2)
            .filter(|w| magnitude(w[0].force_n) > threshold)
            .map(|w| w[1].t_s - w[0].t_s)
            .sum();
        assert_eq!(r.samples, pts.len());
        assert!((r.duration_s - (pts[pts.len() - 1].t_s - pts[0].t_s)).abs() < 1e-12);
        assert!(
            (r.path_length_m - path_length).abs() < 1e-12,
            "{name}: path {} vs {path_length}",
            r.path_length_m
        );
        assert!(path_length > 0.001, "{name} moved {path_length} m");
        assert_eq!(r.peak_force_n, peak, "{name}");
        assert!(peak > 0.01, "{name}: peak {peak} N");
        assert!((r.time_above_threshold_s - above).abs() < 1e-9, "{name}");
        assert!(r.time_above_threshold_s > 0.0 && r.time_in_contact_s > 0.0);
    }
    assert!((report.duration_s - duration).abs() < 1e-12);

    // 3. `fissure replay --recording`: the recorded trajectories against a
    // fresh stepped server give the same forces, to the bit.
    let replayed_plans = fissure_cli::client::report::trajectories(&path)?;
    assert_eq!(
        replayed_plans
            .iter()
            .map(|p| p.0.as_str())
            .collect::<Vec<_>>(),
        ["left", "right"]
    );
    let (replayed, _) = run(stepped(2, None), &replayed_plans).await?;
    for (name, rows) in &live {
        let again = &replayed[name];
        assert_eq!(again.len(), rows.len());
        for (a, b) in rows.iter().zip(again) {
            assert_eq!(
                (a.sequence, a.force_n.map(f64::to_bits), a.model_frame),
                (b.sequence, b.force_n.map(f64::to_bits), b.model_frame),
                "{name}: replayed sample {} differs",
                a.sequence
            );
        }
    }
    Ok(())
}
