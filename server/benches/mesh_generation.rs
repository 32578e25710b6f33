//! Counts and generation times of the brain phantom presets (each also with
//! `--proven`): nodes, tetrahedra, surface triangles, the dihedral range and
//! the tetrahedra whose centroid lies inside a fissure gap. Run with
//! `cargo bench -p fissure-engine --bench mesh_generation`; `PHANTOM_SWEEP`
//! (`"h,surface,levels,band,rate[,proven];..."`) adds coarse-preset variants.

use fissure_engine::mesh::phantom::{self, PhantomParams};
use fissure_engine::mesh::stuffing;
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

fn main() {
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
