//! End to end on the `cube` scene: a pose in, a force out, through every layer.

use fissure_engine::fem;
use fissure_engine::sim::{Mode, SimOptions};
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use nalgebra::Vector3;

/// Lays the plate flat, face A down (-z), tip towards +y (see cube.toml).
const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
/// Handle height at which face A touches the cube's top (z = 40 mm), m.
const TOUCH_Z: f64 = 0.04 + 0.00075;

fn stepped() -> SimOptions {
    SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    }
}

/// (a) A spatula face pushed 2 mm into the cube: the force opposes the push,
/// has no tangential part (frictionless contact with a flat face), and
/// equals, to 1e-9, the same contact problem solved by the `direct`
/// strategy (sparse elimination of the working set's rows, no compliance
/// columns), an independent path from the scene's `compliance`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pushed_face_force_matches_direct_solve() -> anyhow::Result<()> {
    let server = TestServer::start("cube", stepped(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let (x, y) = (0.011, 0.005);
    let depth = 0.002;
    let mut last = None;
    for i in 0..=300u64 {
        let t = i as f64 * 1e-3;
        // Down from 2 mm above the top to 2 mm into it over 0.1 s, then hold.
        let s = (t / 0.1).min(1.0);
        let z = TOUCH_Z + 0.002 - (0.002 + depth) * s;
        let sample = haptic.send(pose(t, i + 1, [x, y, z], FLAT_DOWN)).await?;
        assert!(sample.rejection.is_none(), "{:?}", sample.rejection);
        last = Some(sample);
    }
    let last = last.expect("samples");
    let f = last.force_n.expect("force");
    let force = Vector3::new(f.x, f.y, f.z);
    // Opposes the push (-z): the tissue pushes the spatula up.
    assert!(force.z > 0.0, "force {force:?} does not oppose the push");
    // Frictionless on a flat face: every contact force is along the normal.
    assert!(
        force.xy().norm() <= 1e-12 * force.z,
        "force {force:?} has a tangential part"
    );
    assert!(last.contact_count > 0);

    // The rows of the last step, solved independently.
    let snap = server.sim.snapshot();
    let fm = &snap.force_model;
    assert!(!fm.step_rows.is_empty(), "no contact in the last step");
    let model = server.sim.model();
    let rows: Vec<fem::ContactRow> = fm.step_rows.iter().map(|r| r.row).collect();
    // The tissue the plate holds sits exactly on its face: a held vertex
    // has u_z = -depth, a held polygon point a zero gap.
    for (r, &l) in fm.step_rows.iter().zip(&fm.step_lambda) {
        if l > 0.0 {
            let gap = r.row.gap_free_m + r.row.normal_motion(&snap.displacements);
            assert!(gap.abs() < 1e-9, "row {:x}: gap {gap} m", r.key);
            if !r.row.is_point() {
                let u = snap.displacements[r.row.node as usize];
                assert!((u.z + depth).abs() < 1e-9, "node {}: {u:?}", r.row.node);
            }
        }
    }
    let material = fem::Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    let mut direct = fem::build_solver(
        fem::Strategy::Direct,
        &model.mesh,
        material,
        &model.fixed,
        &fem::SolverOptions::default(),
    )?;
    let mut answer = fem::ContactAnswer::default();
    direct.solve_contact(&rows, &mut answer)?;
    let expected: Vector3<f64> = rows
        .iter()
        .zip(&answer.multipliers)
        .map(|(r, l)| -r.dir * *l)
        .sum();
    let err = (force - expected).norm() / expected.norm();
    assert!(
        err < 1e-9,
        "force {force:?} vs direct {expected:?}: relative error {err:.2e}"
    );
    haptic.close().await;
    server.stop().await
}

/// (b) A second claim of a claimed instrument fails with ALREADY_EXISTS; an
/// unknown instrument with NOT_FOUND; after release the instrument can be
/// claimed again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn claims_are_exclusive() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let first = Haptic::open(&mut client, "left", None).await?;
    let err = Haptic::open(&mut client, "left", None).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::AlreadyExists, "{err}");
    assert!(
        err.message().contains("left") && err.message().contains("already claimed"),
        "{err}"
    );
    let err = Haptic::open(&mut client, "scalpel", None)
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::NotFound, "{err}");
    assert!(err.message().contains("left, right"), "{err}");
    // The other instrument is free.
    let other = Haptic::open(&mut client, "right", None).await?;
    first.close().await;
    other.close().await;
    let again = Haptic::open(&mut client, "left", None).await?;
    again.close().await;
    server.stop().await
}

/// (c) A pose with a NaN is rejected with INVALID_ARGUMENT, changes nothing, and
/// the stream keeps serving the next valid pose.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nan_pose_is_rejected_and_stream_continues() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let ok = haptic
        .send(pose(0.0, 1, [0.011, 0.005, 0.05], FLAT_DOWN))
        .await?;
    assert!(ok.rejection.is_none());
    let bad = haptic
        .send(pose(0.001, 2, [0.011, f64::NAN, 0.05], FLAT_DOWN))
        .await?;
    let rejection = bad.rejection.expect("NaN pose must be rejected");
    assert_eq!(rejection.code, tonic::Code::InvalidArgument as i32);
    assert!(
        rejection.message.contains("position_m.y"),
        "{}",
        rejection.message
    );
    let bad_q = haptic
        .send(pose(0.001, 2, [0.011, 0.005, 0.05], [0.0, 0.0, 0.0, 0.0]))
        .await?;
    assert_eq!(
        bad_q.rejection.expect("zero quaternion").code,
        tonic::Code::InvalidArgument as i32
    );
    // The rejected pose did not advance the sequence: 2 is accepted now.
    let next = haptic
        .send(pose(0.002, 2, [0.011, 0.005, 0.05], FLAT_DOWN))
        .await?;
    assert!(next.rejection.is_none(), "{:?}", next.rejection);
    assert_eq!(next.sequence, 2);
    let stats = client
        .get_stats(fissure_proto::v1::GetStatsRequest {})
        .await?
        .into_inner();
    assert_eq!(stats.rejected_poses, 2);
    haptic.close().await;
    server.stop().await
}

/// (d) Health reports NOT_SERVING while the scene loads and SERVING once it is
/// loaded; reflection lists the service.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_serving_once_loaded() -> anyhow::Result<()> {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    let server = fissure_server::serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
    let url = format!("http://{}", server.addr);
    let channel = tonic::transport::Channel::from_shared(url.clone())?
        .connect()
        .await?;
    let mut health = HealthClient::new(channel);
    let req = || HealthCheckRequest {
        service: "fissure.v1.Fissure".into(),
    };
    let status = health.check(req()).await?.into_inner().status;
    assert_eq!(status, ServingStatus::NotServing as i32);
    // Calls before the scene is loaded are UNAVAILABLE, not errors of the client.
    let mut client = fissure_cli::client::replay::connect(&url).await?;
    let err = client
        .get_scene(fissure_proto::v1::GetSceneRequest {})
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unavailable);

    let (scene, _) = fissure_engine::scene::Scene::load("cube")?;
    let sim = tokio::task::spawn_blocking(move || {
        fissure_engine::sim::Simulation::start(scene, SimOptions::default())
    })
    .await??;
    server.set_simulation(sim.clone()).await;
    let status = health.check(req()).await?.into_inner().status;
    assert_eq!(status, ServingStatus::Serving as i32);
    let scene = client
        .get_scene(fissure_proto::v1::GetSceneRequest {})
        .await?
        .into_inner();
    assert_eq!(scene.name, "cube");
    assert_eq!(scene.units, "SI");
    assert_eq!(scene.instruments.len(), 2);
    let surface = client
        .get_surface(fissure_proto::v1::GetSurfaceRequest {})
        .await?
        .into_inner();
    let model = scene.model.expect("model size");
    assert_eq!(surface.triangles.len() as u32, 3 * model.surface_triangles);
    assert_eq!(
        surface.rest_positions_m.len() as u32,
        3 * model.surface_vertices
    );
    server.shutdown().await?;
    tokio::task::spawn_blocking(move || sim.shutdown()).await?;
    Ok(())
}
