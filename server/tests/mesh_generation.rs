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
        report(name, &phantom::preset_params(name).expect("known"));
    }
    if let Ok(spec) = std::env::var("PHANTOM_SWEEP") {
        // "h,surface,levels,band,rate;..."
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
            report(item, &p);
        }
    }
}
