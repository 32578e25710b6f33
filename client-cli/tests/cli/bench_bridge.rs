//! `fissure bench bridge` on a few samples: every path answers every pose,
//! the round trips are positive and finite, and the surface path reads
//! POLYDATA between its answers.

use fissure_cli::lab::bench::bridge::{BridgeBenchArgs, run, table};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_bridge_path_answers_every_pose() -> anyhow::Result<()> {
    let args = BridgeBenchArgs {
        samples: 200,
        rate_hz: 1000.0,
        warmup: 20,
        path: Vec::new(),
        json: false,
    };
    let r = run(&args).await?;
    let paths: Vec<&str> = r.rows.iter().map(|x| x.path.as_str()).collect();
    assert_eq!(paths, ["udp", "igtl", "igtl+surface"]);
    for x in &r.rows {
        assert_eq!(x.samples, 200, "{x:?}");
        for v in [x.grpc_p50_us, x.grpc_p99_us, x.p50_us, x.p99_us, x.max_us] {
            assert!(v.is_finite() && v > 0.0, "{x:?}");
        }
        assert!(x.p50_us <= x.p99_us && x.p99_us <= x.max_us, "{x:?}");
        assert_eq!(x.added_p99_us, x.p99_us - x.grpc_p99_us);
    }
    // 0.22 s at the cube's 20 ms deformation interval: frames arrive.
    assert!(r.rows[2].polydata >= 2, "{:?}", r.rows[2]);
    assert_eq!(r.rows[1].polydata, 0);
    let t = table(&r);
    assert!(t.contains("igtl+surface") && t.contains("added p99"), "{t}");
    Ok(())
}
