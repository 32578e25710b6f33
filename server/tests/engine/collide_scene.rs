//! The GPU collision backend is selectable per scene: a scene with
//! `backend = "gpu"` builds a GPU ray backend (any wgpu adapter, lavapipe
//! included; without one it falls back to the CPU and says so) and, stepped
//! through the deformation loop's stages (collision query, FEM solve, refit on
//! the deformed surface), gives exactly the contacts of the same scene on the
//! CPU.

use faer::Par;
use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::scene::{CollisionBackend, Scene};
use fissure_engine::sim::core::engine::{ContactQuery, Deformer, Model, RowRule, ray_backend};
use fissure_engine::sim::core::rows::{Anchors, FreePositions};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};
use std::sync::Arc;

fn scene_text(name: &str) -> String {
    let path = format!("{}/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn home(scene: &Scene, i: usize) -> Isometry3<f64> {
    let spec = &scene.instruments[i];
    let [w, x, y, z] = spec.home_orientation;
    let [px, py, pz] = spec.home_position_m;
    Isometry3::from_parts(
        Translation3::new(px, py, pz),
        UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
    )
}

#[test]
fn gpu_scene_gives_the_cpu_scenes_contacts() {
    let text = scene_text("v-valley");
    assert!(text.contains("method = \"bvh\"\n"));
    let gpu_text = text.replace(
        "method = \"bvh\"\n",
        "method = \"bvh\"\nbackend = \"gpu\"\n",
    );
    let cpu_scene = Scene::parse(&text, "v-valley").unwrap();
    let gpu_scene = Scene::parse(&gpu_text, "v-valley (gpu)").unwrap();
    assert_eq!(gpu_scene.collision.backend, CollisionBackend::Gpu);
    assert_eq!(cpu_scene.collision.backend, CollisionBackend::Cpu);

    let model = Model::build(&cpu_scene).unwrap();
    let backend = ray_backend(&gpu_scene, &model, &model.rest_surface);
    assert_eq!(backend.method(), "bvh");
    if backend.backend() != "gpu" {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI is set but the GPU scene fell back to the CPU (no adapter?)"
        );
        eprintln!("no GPU adapter: the GPU scene runs on the CPU fallback");
    }
    drop(backend);

    let mut cpu = ContactQuery::new(&cpu_scene, Par::Seq);
    let mut gpu = ContactQuery::new(&gpu_scene, Par::Seq);
    let mut deformer = Deformer::new(&cpu_scene, &model, ColumnPolicy::Compute, None).unwrap();
    let mut snap = model.rest_snapshot(&cpu_scene, 0, 0.0);
    let rule = RowRule::of(&cpu_scene);
    let mut rows = Vec::new();
    let mut h_cpu = vec![model.new_history(0)];
    let mut h_gpu = vec![model.new_history(0)];
    let start = home(&cpu_scene, 0);
    let mut touched = 0;
    // The tip goes from 5 mm above the block (z = 35 mm) to 11.5 mm in 8 steps,
    // then on to 10.3 mm (0.3 mm above the groove's bottom) in 0.3 mm steps:
    // the 1.5 mm plate meets the V's walls below z = 11.25 mm.
    let downs: Vec<f64> = (0..=8)
        .map(|k| 0.0235 * k as f64 / 8.0)
        .chain((1..=4).map(|k| 0.0235 + 0.0003 * k as f64))
        .collect();
    for (k, &down) in downs.iter().enumerate() {
        let pose = Translation3::new(0.0, 0.0, -down) * start;
        let a = cpu.query_all(&model, &snap, &[pose], &mut h_cpu).clone();
        let b = gpu.query_all(&model, &snap, &[pose], &mut h_gpu).clone();
        assert_eq!(
            a, b,
            "step {k}: GPU scene contacts differ from the CPU scene's"
        );
        assert_eq!(h_cpu[0].flags(), h_gpu[0].flags(), "step {k}: histories");
        if !a.candidates.is_empty() {
            touched += 1;
        }
        // Deform, publish the new surface: both queries refit on it next step.
        rows.clear();
        rule.rows(
            &model,
            &a,
            &FreePositions::Rest(&model.mesh.nodes),
            &[],
            &Anchors::default(),
            &[pose],
            &mut rows,
        );
        deformer.solve(&rows, &[]).unwrap();
        let u = deformer.displacements();
        let surface: Vec<Point3<f64>> = model
            .rest_surface
            .iter()
            .zip(&model.surface.to_volume)
            .map(|(p, &v)| p + u[v as usize])
            .collect();
        snap.surface = Arc::new(surface);
    }
    assert!(
        touched >= 2,
        "the spatula reaches the groove's walls ({touched} steps in contact)"
    );
}
