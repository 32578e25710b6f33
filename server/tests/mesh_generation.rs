//! Generation of tetrahedral models: the brain phantom presets, isosurface
//! stuffing quality and meshing of closed surfaces.

use fissure_server::mesh::phantom::{self, PhantomParams};
use fissure_server::mesh::stuffing;
use std::time::Instant;

fn report(name: &str, params: &PhantomParams) {
    let t0 = Instant::now();
    let p = phantom::generate_with(params).expect("generates");
    let dt = t0.elapsed().as_secs_f64();
    let b = p.mesh.boundary();
    let shape = phantom::BrainShape::new(params.fissures);
    let in_gap = p
        .mesh
        .tets
        .iter()
        .filter(|t| {
            let c = t.iter().fold(nalgebra::Vector3::zeros(), |a, &v| {
                a + p.mesh.nodes[v as usize].coords
            }) / 4.0;
            shape.fissures(&nalgebra::Point3::from(c))
                < -0.25
                    * params
                        .fissures
                        .sylvian_width
                        .min(params.fissures.interhemispheric_width)
        })
        .count();
    println!("{name}: {in_gap} tetrahedra with the centroid inside a fissure gap");
    let (lo, hi) = stuffing::dihedral_range(&p.mesh);
    println!(
        "{name}: {} nodes, {} tets, {} surface triangles, dihedral {lo:.2}..{hi:.2} deg, {dt:.3} s",
        p.mesh.nodes.len(),
        p.mesh.tets.len(),
        b.triangles.len()
    );
}

/// Prints counts and generation times of the presets; run with
/// `cargo test --release -p fissure-server --test mesh_generation -- --ignored --nocapture`.
#[test]
#[ignore]
fn preset_counts_and_times() {
    for name in phantom::PRESETS {
        let params = phantom::preset_params(name).expect("known");
        report(name, &params);
        report(
            &format!("{name} --proven"),
            &PhantomParams {
                proven: true,
                ..params
            },
        );
    }
    if let Ok(spec) = std::env::var("PHANTOM_SWEEP") {
        // "h,surface,levels,band,rate[,proven];..."
        for item in spec.split(';') {
            let v: Vec<f64> = item
                .split(',')
                .map(|x| x.parse().expect("number"))
                .collect();
            let mut p = phantom::preset_params("coarse").expect("known");
            p.spacing = v[0];
            p.surface_size = v[1];
            p.levels = v[2] as u32;
            p.band = v[3];
            p.rate = v[4];
            p.proven = v.get(5).is_some_and(|&x| x != 0.0);
            p.fissures = phantom::FissureSizes::default();
            report(item, &p);
        }
    }
}

fn within(actual: usize, target: f64, tol: f64) -> bool {
    (actual as f64 - target).abs() <= tol * target
}

/// The paper presets' node, tetrahedron and surface-triangle counts are within
/// 15% of the paper's models (release: about 0.1-0.2 s each).
#[test]
#[ignore]
fn paper_presets_match_the_paper_counts() {
    for (name, nodes, tets, tris) in [
        ("paper-34k", 9.1e3, 34e3, 12.6e3),
        ("paper-48k", 12.3e3, 48e3, 15.9e3),
    ] {
        let p = phantom::preset(name).expect("generates");
        let b = p.mesh.boundary();
        assert!(
            within(p.mesh.nodes.len(), nodes, 0.15),
            "{name}: {} nodes",
            p.mesh.nodes.len()
        );
        assert!(
            within(p.mesh.tets.len(), tets, 0.15),
            "{name}: {} tets",
            p.mesh.tets.len()
        );
        assert!(
            within(b.triangles.len(), tris, 0.15),
            "{name}: {} triangles",
            b.triangles.len()
        );
        let (lo, hi) = stuffing::dihedral_range(&p.mesh);
        assert!(
            lo > stuffing::MIN_DIHEDRAL_DEG && hi < stuffing::MAX_DIHEDRAL_DEG,
            "{name}: {lo}..{hi}"
        );
    }
}

#[test]
fn coarse_landmarks_open_into_the_meshed_gap() {
    let p = phantom::preset("coarse").expect("generates");
    let surf = p.mesh.boundary();
    for fl in [
        p.landmarks.sylvian_left,
        p.landmarks.sylvian_right,
        p.landmarks.interhemispheric,
    ] {
        // Both walls of the fissure are meshed surface: some boundary vertex lies
        // within 1 mm of each wall plane near mid-depth.
        let mid = fl.entry + fl.direction.into_inner() * (0.5 * fl.depth);
        for side in [-1.0, 1.0] {
            let wall = mid + fl.normal.into_inner() * (side * 0.5 * fl.width);
            let near = surf
                .to_volume
                .iter()
                .map(|&v| (p.mesh.nodes[v as usize] - wall).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(
                near < 0.008,
                "no surface vertex near the wall at {wall:?}: {near}"
            );
        }
    }
}

#[test]
fn closed_box_surface_meshes_to_its_volume() {
    use fissure_server::mesh::from_surface::{SurfaceMeshing, mesh_surface};
    // The boundary of a Kuhn-subdivided box is a closed triangle surface.
    let block = fissure_server::mesh::blocks::cuboid([0.04, 0.03, 0.02], [4, 3, 2]);
    let s = block.boundary();
    let mut verts = Vec::new();
    s.gather(&block.nodes, &mut verts);
    let m = mesh_surface(
        &verts,
        &s.triangles,
        &SurfaceMeshing {
            spacing: 0.004,
            levels: 0,
            rate: 0.0,
        },
    )
    .expect("meshes")
    .mesh;
    let vol: f64 = (0..m.tets.len()).map(|t| m.signed_volume(t)).sum();
    let exact = 0.04 * 0.03 * 0.02;
    // Stuffing rounds the box's edges and corners at the scale of the spacing.
    assert!((vol - exact).abs() < 0.05 * exact, "{vol} vs {exact}");
}
