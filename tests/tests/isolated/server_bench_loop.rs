//! `fissure bench loop` end to end on the `cube` scene (short, debug build):
//! the figures it reports are consistent with what it ran. Speed targets are
//! the benchmark's business, not this test's.

use fissure_cli::lab::bench::loops::{LoopBenchArgs, run};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bench_loop_reports_consistent_figures() -> anyhow::Result<()> {
    let _alone = crate::alone().await;
    let args = LoopBenchArgs {
        scene: "cube".into(),
        duration_s: 1.0,
        watchers: 2,
        rate_hz: 1000.0,
        rt_priority: 0,
        transport_rt_priority: 0,
        traversal: Some(fissure_engine::scene::Traversal::PerRay),
        json: true,
        ..Default::default()
    };
    let r = run(&args).await?;
    assert_eq!(r.scene, "cube");
    assert_eq!(r.traversal, "per-ray", "the override reached the scene");
    assert_eq!(r.clients, 2);
    assert_eq!(r.watchers, 2);
    // 0 asks for no real-time scheduling, and the report says so.
    assert!(!r.realtime);
    assert!(!r.transport_realtime);
    // Every tick sent a pose and every pose was answered (late or not).
    assert_eq!(r.samples_sent, 2000);
    assert_eq!(r.samples_answered, 2000);
    assert!(r.samples_pending <= r.samples_answered);
    assert!(r.missed_samples <= r.samples_sent);
    assert!(r.missed_by_round_trip <= r.missed_samples);
    assert!(r.missed_outside_stalls <= r.missed_samples);
    // A stall probe ran on every CPU the process may use.
    #[cfg(target_os = "linux")]
    assert_eq!(
        r.stall_probe_cpus,
        fissure_engine::sim::runtime::priority::allowed_cpus().map_or(0, |c| c.len())
    );
    assert!(r.stall_probe_cpus >= 1 || !cfg!(target_os = "linux"));
    if r.machine_stalls == 0 {
        assert_eq!(r.machine_stall_max_us, 0.0);
    } else {
        assert!(r.machine_stall_max_us > fissure_cli::lab::bench::loops::STALL_THRESHOLD_US);
    }
    assert!(r.duration_s >= 0.999, "{}", r.duration_s);
    for (name, v) in [
        ("rtt_p50_us", r.rtt_p50_us),
        ("rtt_p99_us", r.rtt_p99_us),
        ("server_force_p50_us", r.server_force_p50_us),
        ("server_force_p99_us", r.server_force_p99_us),
    ] {
        assert!(v.is_finite() && v > 0.0, "{name} = {v}");
    }
    assert!(r.rtt_p50_us <= r.rtt_p99_us && r.rtt_p99_us <= r.rtt_max_us);
    assert!(r.server_force_p99_us <= r.server_force_max_us);
    // The collision query is part of the force sample.
    assert!(r.force_collision_p50_us > 0.0 && r.force_collision_p50_us <= r.server_force_p50_us);
    assert!(r.force_collision_p99_us <= r.force_collision_max_us);
    // The server's compute time is part of the round trip.
    assert!(r.server_force_p50_us < r.rtt_p50_us);
    // The bundled cube trajectories press the surface: contact, steps, frames.
    assert!(r.contact_count_max > 0);
    assert!(r.frames_published > 0 && r.deform_hz > 0.0);
    assert!(r.frames_delivered > 0);
    assert!(r.frames_delivered <= 2 * (r.frames_published + 1));
    let json = serde_json::to_value(&r)?;
    for key in [
        "rtt_p50_us",
        "rtt_p99_us",
        "server_force_p99_us",
        "deform_hz",
        "frames_delivered",
        "missed_samples",
        "missed_outside_stalls",
        "machine_stalls",
    ] {
        assert!(json.get(key).is_some_and(|v| v.is_number()), "{key}");
    }
    assert!(json.get("realtime").is_some_and(|v| v.is_boolean()));
    assert!(
        json.get("transport_realtime")
            .is_some_and(|v| v.is_boolean())
    );
    Ok(())
}
