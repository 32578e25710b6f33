//! The force loops' scheduling: a claim's force loop runs under SCHED_FIFO at
//! the configured priority where the process may ask for it. In the
//! `isolated` binary, alone in the process while it runs, so that no other
//! test's force loop thread shares the process.

use fissure_engine::sim::SimOptions;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};

/// Lays the plate flat, face A down, tip towards +y (see cube.toml).
const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Home position of the cube scene's left instrument, m.
const LEFT_HOME: [f64; 3] = [0.011, 0.005, 0.04275];

/// Scheduling policy and real-time priority of this process's thread named
/// `name` (Linux: fields 41 and 40 of `/proc/self/task/<tid>/stat`).
#[cfg(target_os = "linux")]
fn thread_policy(name: &str) -> Option<(u32, u32)> {
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let dir = task.ok()?.path();
        let comm = std::fs::read_to_string(dir.join("comm")).ok()?;
        if comm.trim() != name {
            continue;
        }
        let stat = std::fs::read_to_string(dir.join("stat")).ok()?;
        let rest = &stat[stat.rfind(')')? + 1..];
        let fields: Vec<&str> = rest.split_whitespace().collect();
        // Field 3 (state) is fields[0]: rt_priority is field 40, policy 41.
        return Some((fields[38].parse().ok()?, fields[37].parse().ok()?));
    }
    None
}

/// A claim's force loop runs under SCHED_FIFO at the configured priority
/// where the process may ask for it (and at normal priority where it may not,
/// or when 0 asks for none), and serves either way.
#[cfg(target_os = "linux")]
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_loop_runs_realtime_where_permitted() -> anyhow::Result<()> {
    use fissure_engine::sim::runtime::priority;
    const SCHED_OTHER: u32 = 0;
    const SCHED_FIFO: u32 = 1;
    let _alone = crate::alone().await;
    let permitted = std::thread::spawn(|| priority::raise_current_thread(7).is_ok())
        .join()
        .expect("probe thread");
    for asked in [13u8, 0] {
        let options = SimOptions {
            force_loop_rt_priority: asked,
            ..SimOptions::default()
        };
        let server = TestServer::start("cube", options, ServeOptions::default()).await?;
        let mut client = server.client().await?;
        let mut haptic = Haptic::open(&mut client, "left", None).await?;
        let s = haptic.send(pose(0.0, 1, LEFT_HOME, FLAT_DOWN)).await?;
        assert!(s.rejection.is_none(), "{:?}", s.rejection);
        let got = thread_policy("force-loop-left").expect("the force loop thread exists");
        if permitted && asked > 0 {
            assert_eq!(got, (SCHED_FIFO, u32::from(asked)));
        } else {
            assert_eq!(got, (SCHED_OTHER, 0));
        }
        haptic.close().await;
        server.stop().await?;
        // The loop's thread ends with its stream.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while thread_policy("force-loop-left").is_some() {
            assert!(
                std::time::Instant::now() < deadline,
                "the force loop thread did not end"
            );
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
    }
    Ok(())
}
