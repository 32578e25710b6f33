//! Every embedded scene loads and runs; what a scene declares is what is built.

use fissure_engine::scene::{EMBEDDED, RoiSpec, Scene};
use fissure_engine::sim::core::pose::RawPose;
use fissure_engine::sim::{Mode, SimOptions, Simulation};

fn stepped() -> SimOptions {
    SimOptions {
        mode: Some(Mode::Stepped { clients: 1 }),
        ..SimOptions::default()
    }
}

/// Runs instrument `name` of `sim` along `poses` (t, position) at its home
/// orientation and returns the last force sample.
fn drive(
    sim: &std::sync::Arc<Simulation>,
    name: &str,
    poses: &[(f64, [f64; 3])],
) -> fissure_engine::sim::ForceOut {
    let (_, spec) = sim.scene().instrument(name).expect("instrument");
    let q = spec.home_orientation;
    let mut claim = sim.claim(name).expect("claim");
    let mut last = None;
    for (i, (t, p)) in poses.iter().enumerate() {
        let raw = RawPose {
            t_s: *t,
            sequence: i as u64 + 1,
            position_m: *p,
            orientation: q,
        };
        last = Some(claim.force_sample(&raw).expect("valid pose"));
    }
    last.expect("poses")
}

/// The scene's own numbers reach the model: instruments, node counts, sizes.
#[test]
fn every_embedded_scene_starts() {
    for (name, _) in EMBEDDED {
        let (scene, _) = Scene::load(name).unwrap();
        let sim = Simulation::start(scene.clone(), SimOptions::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let model = sim.model();
        assert_eq!(model.instruments.len(), scene.instruments.len(), "{name}");
        for (inst, spec) in model.instruments.iter().zip(&scene.instruments) {
            assert_eq!(inst.per_face, spec.nodes_per_face as usize, "{name}");
        }
        assert!(!model.fixed.is_empty(), "{name}");
        assert_eq!(model.rest_surface.len(), model.surface.to_volume.len());
        let snap = sim.snapshot();
        assert_eq!(snap.frame, 0);
        assert_eq!(snap.surface.len(), model.rest_surface.len());
        sim.shutdown();
    }
}

/// The Sylvian scene: a spatula inserted into the fissure and lifted pushes the
/// upper wall; the force on the spatula points down (it opposes the lift).
#[test]
fn sylvian_spatula_lifts_the_upper_wall() {
    // Held at the brain stem only (the scene's foundation taken away): the
    // lifted wall moves by about the push.
    let (mut scene, _) = Scene::load("sylvian").unwrap();
    scene.foundation = None;
    let home = scene.instruments[0].home_position_m;
    let sim = Simulation::start(scene, stepped()).unwrap();
    let mut poses = Vec::new();
    // Insert 20 mm along +x in 0.2 s, then lift 3 mm (+z) in 0.2 s, hold.
    for i in 0..=500 {
        let t = i as f64 * 1e-3;
        let s = (t / 0.2).min(1.0);
        let lift = ((t - 0.2) / 0.2).clamp(0.0, 1.0);
        poses.push((t, [home[0] + 0.020 * s, home[1], home[2] + 0.003 * lift]));
    }
    let f = drive(&sim, "left", &poses);
    assert!(f.contact_count > 0, "no contact");
    assert!(
        f.force_n.z < 0.0,
        "force {:?} does not oppose the lift",
        f.force_n
    );
    // Mostly along the lift; the no-slip contact adds smaller tangential parts.
    assert!(
        f.force_n.z.abs() > f.force_n.x.abs().max(f.force_n.y.abs()),
        "force {:?}",
        f.force_n
    );
    let snap = sim.snapshot();
    let frame = snap.frame_summary.clone();
    assert!(frame.solver_error.is_none());
    // The wall the spatula pushes moved up by about the push (3 mm minus
    // the 1 mm clearance): the nodes it holds, on its upper face. (The
    // brain, held at the stem only, also swings a little as a whole, so
    // the largest displacement elsewhere can exceed the push.)
    let fm = &snap.force_model;
    let lifted: Vec<f64> = fm
        .step_rows
        .iter()
        .zip(&fm.step_lambda)
        .filter(|(r, l)| r.owner == 0 && **l > 0.0 && r.row.dir.z > 0.9)
        .map(|(r, _)| snap.displacements[r.row.node as usize].z)
        .collect();
    assert!(!lifted.is_empty(), "nothing pushed up");
    let mean = lifted.iter().sum::<f64>() / lifted.len() as f64;
    assert!(
        mean > 0.0015 && mean < 0.0025,
        "the held wall rose {mean} m"
    );
    sim.shutdown();
}

/// The default phantom scenes are held by the elastic foundation, and two
/// stepped runs of the same poses give bit-identical forces and surfaces.
#[test]
fn foundation_scenes_replay_bit_identically() {
    let (scene, _) = Scene::load("interhemispheric").unwrap();
    assert!(scene.foundation.is_some());
    let home = scene.instruments[0].home_position_m;
    // Down 20 mm (the tip 15 mm into the fissure) in 0.1 s, then 2 mm
    // along +x (1 mm into the wall) in 0.05 s.
    let poses: Vec<(f64, [f64; 3])> = (0..=150)
        .map(|i| {
            let t = i as f64 * 1e-3;
            let down = (t / 0.1).min(1.0);
            let side = ((t - 0.1) / 0.05).clamp(0.0, 1.0);
            (t, [home[0] + 0.002 * side, home[1], home[2] - 0.020 * down])
        })
        .collect();
    let run = || {
        let sim = Simulation::start(scene.clone(), stepped()).unwrap();
        assert!(sim.model().foundation.is_some());
        let f = drive(&sim, "left", &poses);
        let frame = sim.snapshot().frame_summary.clone();
        sim.shutdown();
        (f.force_n, frame)
    };
    let (fa, a) = run();
    let (fb, b) = run();
    assert!(a.solver_error.is_none(), "{:?}", a.solver_error);
    assert!(a.frame > 0 && a.max_displacement_m > 0.0);
    assert_eq!(fa, fb);
    assert_eq!(a.positions, b.positions);
    assert_eq!(a.rigid, b.rigid);
}

/// A region of interest crops the FEM to the tissue near the fissure: fewer
/// tetrahedra, the cut fixed. Cropping stiffens the model (more of it is held),
/// and less so as the region grows: the force approaches the full model's.
#[test]
fn region_of_interest_crops_and_converges() {
    // Held at the brain stem only (the scene's foundation taken away).
    let (mut scene, _) = Scene::load("sylvian").unwrap();
    scene.foundation = None;
    let home = scene.instruments[0].home_position_m;
    let mut poses = Vec::new();
    for i in 0..=300 {
        let t = i as f64 * 1e-3;
        let lift = ((t - 0.1) / 0.1).clamp(0.0, 1.0);
        poses.push((
            t,
            [
                home[0] + 0.020 * (t / 0.1).min(1.0),
                home[1],
                home[2] + 0.003 * lift,
            ],
        ));
    }
    let full = Simulation::start(scene.clone(), stepped()).unwrap();
    let f_full = drive(&full, "left", &poses).force_n;
    let n_full = full.model().mesh.tets.len();
    full.shutdown();
    assert!(f_full.z < 0.0);
    let mut ratios = Vec::new();
    for distance in [0.03, 0.05] {
        let mut s = scene.clone();
        s.roi = Some(RoiSpec {
            centre_m: [-0.055, 0.01, 0.0],
            plane_normal: None,
            distance_m: distance,
        });
        let sim = Simulation::start(s, stepped()).unwrap();
        let n = sim.model().mesh.tets.len();
        assert!(n < n_full, "cropped {n} of {n_full} tets");
        let f = drive(&sim, "left", &poses).force_n;
        sim.shutdown();
        assert!(f.z < 0.0 && f.iter().all(|c| c.is_finite()), "{f:?}");
        ratios.push(f.norm() / f_full.norm());
    }
    assert!(
        ratios[0] > 1.0 && ratios[1] > 0.95,
        "cropped/full force ratios {ratios:?}"
    );
    assert!(
        ratios[1] < ratios[0],
        "a larger region must be closer to the full model: {ratios:?}"
    );
}

/// A nonlinear strategy (corotational) gives the force loop the tangent
/// compliance of its last step (`fem::tangent`): the force loop's contact
/// problem is the expansion of the full one about that step, so a sample at
/// the step's own pose gives the step's force: to 1% here (measured 0.5%),
/// since the step searched its rows on the shape of the step before it and
/// a sample searches them on the step's own shape (the deformed contact
/// geometry of the nonlinear strategies), so the two see slightly different
/// rows.
#[test]
fn corotational_force_samples_at_the_step_pose_give_the_step_force() {
    let (mut scene, _) = Scene::load("cube").unwrap();
    scene.solver.strategy = fissure_engine::scene::Strategy::Corotational;
    let home = scene.instruments[0].home_position_m;
    let sim = Simulation::start(scene, stepped()).unwrap();
    let mut poses = Vec::new();
    // Down 4 mm from 2 mm above the top (2 mm into it) in 0.1 s, then hold.
    for i in 0..=200 {
        let t = i as f64 * 1e-3;
        poses.push((t, [home[0], home[1], home[2] - 0.004 * (t / 0.1).min(1.0)]));
    }
    let f = drive(&sim, "left", &poses);
    let frame = sim.snapshot().frame_summary.clone();
    sim.shutdown();
    assert!(frame.solver_error.is_none(), "{:?}", frame.solver_error);
    let step_force = frame.instruments[0].force_n;
    assert!(
        f.force_n.z > 0.0,
        "force {:?} does not oppose the push",
        f.force_n
    );
    assert!(
        (f.force_n - step_force).norm() <= 1e-2 * step_force.norm().max(1e-12),
        "{:?} vs {step_force:?}",
        f.force_n
    );
}
