//! Scenes whose model is a mesh file: a file in millimetres is refused with
//! the unit and the scale to use, `model.scale` converts it; a file whose
//! boundary is not a closed manifold is refused naming the edge and where it
//! is.

use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::blocks::cube;
use fissure_engine::mesh::io;
use fissure_engine::scene::Scene;
use fissure_engine::sim::{SimOptions, Simulation};
use nalgebra::Point3;
use std::path::Path;

/// The cube scene with its model replaced by `[model]` lines.
fn scene_with_model(model: &str) -> anyhow::Result<Scene> {
    let text = include_str!("../../../server/scenes/cube.toml");
    let start = text.find("[model]").expect("[model]");
    let end = text.find("[material]").expect("[material]");
    let text = format!("{}[model]\n{model}\n\n{}", &text[..start], &text[end..]);
    Ok(Scene::parse(&text, "cube with a model file")?)
}

fn start(scene: Scene) -> Result<std::sync::Arc<Simulation>, String> {
    Simulation::start(scene, SimOptions::default()).map_err(|e| e.to_string())
}

fn toml_path(p: &Path) -> String {
    p.display().to_string().replace('\\', "/")
}

/// The cube scene's 40 mm cube written in millimetres (40 units across)
/// is refused, naming millimetres and `scale = 0.001`; with `scale = 0.001`
/// it loads as the 40 mm cube (bounds 0..0.04 m) and its bottom face is
/// fixed as the scene says; a scale that is not a positive number is a
/// scene error naming `model.scale`.
#[test]
fn a_model_in_millimetres_is_refused_and_model_scale_converts_it() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("cube-mm.vtu");
    io::write_volume(&path, &cube(40.0, 4))?;
    let p = toml_path(&path);
    let err = start(scene_with_model(&format!(
        "kind = \"file\"\npath = \"{p}\""
    ))?)
    .unwrap_err();
    assert!(
        err.contains("40.0000 m across")
            && err.contains("this looks like millimetres")
            && err.contains("use `scale = 0.001`")
            && err.contains("cube-mm.vtu"),
        "{err}"
    );
    let sim = start(scene_with_model(&format!(
        "kind = \"file\"\npath = \"{p}\"\nscale = 0.001"
    ))?)
    .map_err(anyhow::Error::msg)?;
    let (lo, hi) = sim.model().mesh.bounds();
    assert!((hi - lo - nalgebra::Vector3::repeat(0.04)).norm() < 1e-15);
    assert_eq!(
        sim.model().fixed.len(),
        25,
        "the 5 x 5 nodes of the bottom face"
    );
    sim.shutdown();
    for bad in ["0.0", "-1.0", "nan"] {
        let e = scene_with_model(&format!("kind = \"file\"\npath = \"{p}\"\nscale = {bad}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("model.scale"), "{bad}: {e}");
    }
    Ok(())
}

/// Two 10 mm cubes sharing one edge: the boundary has an edge of four
/// triangles. The scene is refused naming that edge, its nodes' positions
/// and the count of such problems.
#[test]
fn a_model_whose_boundary_is_pinched_is_refused_naming_the_edge() -> anyhow::Result<()> {
    let a = cube(0.01, 1);
    let mut nodes = a.nodes.clone();
    let n = nodes.len() as u32;
    let shifted: Vec<Point3<f64>> = a
        .nodes
        .iter()
        .map(|p| Point3::new(p.x + 0.01, p.y + 0.01, p.z))
        .collect();
    // Reuse the nodes the second cube shares with the first (one edge).
    let mut map = Vec::new();
    for q in &shifted {
        match a.nodes.iter().position(|p| (p - q).norm() < 1e-15) {
            Some(i) => map.push(i as u32),
            None => {
                map.push(nodes.len() as u32);
                nodes.push(*q);
            }
        }
    }
    assert_eq!(nodes.len() as u32, n + 6, "two nodes shared");
    let mut tets = a.tets.clone();
    tets.extend(a.tets.iter().map(|t| t.map(|v| map[v as usize])));
    let mesh = TetMesh::new(nodes, tets)?;
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("pinched.vtu");
    io::write_volume(&path, &mesh)?;
    let scene = scene_with_model(&format!("kind = \"file\"\npath = \"{}\"", toml_path(&path)))?;
    let err = start(scene).unwrap_err();
    assert!(
        err.contains("pinched.vtu")
            && err.contains("not a closed manifold")
            && err.contains("belongs to 4 boundary triangles")
            && err.contains("(0.010000, 0.010000, 0.000000) m")
            && err.contains("(0.010000, 0.010000, 0.010000) m"),
        "{err}"
    );
    Ok(())
}
