//! Criterion benchmark of one collision query (refit, rays, pairs, culling
//! and enforced displacements), brute force against the BVH: one spatula pair
//! at 150 nodes a face lying on a cuboid surface of 2,880 triangles, queries
//! alternating the rest surface and a locally bumped one so that every BVH
//! query refits. The paper-size figures come from `fissure bench collision`.

use criterion::{Criterion, criterion_group, criterion_main};
use fissure_engine::collide::{
    BruteForce, Bvh, ContactOutput, ContactQuery, DetectOptions, History, HistoryMode, Instrument,
    NodeLayout, Plate, RayBackend, Stage, Tool, Workspace, detect_many,
};
use fissure_engine::mesh::blocks::cuboid;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::hint::black_box;

fn query(c: &mut Criterion) {
    let mesh = cuboid([0.08, 0.06, 0.05], [20, 15, 12]);
    let s = mesh.boundary();
    let mut rest = Vec::new();
    s.gather(&mesh.nodes, &mut rest);
    let tris = s.triangles;
    let to_volume: Vec<u32> = (0..rest.len() as u32).collect();
    // Two plates on the top face (z = 50 mm), length along +x, face B 0.5 mm in.
    let rot = UnitQuaternion::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
    let poses: Vec<Isometry3<f64>> = [0.012, 0.038]
        .map(|x| Isometry3::from_parts(Translation3::new(x, 0.03011, 0.05), rot))
        .to_vec();
    let bump = Point3::new(0.04, 0.03, 0.05);
    let bumped: Vec<Point3<f64>> = rest
        .iter()
        .map(|p| {
            let r2 = (p - bump).norm_squared() / (0.015 * 0.015);
            if r2 < 1.0 {
                p - Vector3::z() * (2e-4 * (1.0 - r2) * (1.0 - r2))
            } else {
                *p
            }
        })
        .collect();
    let inst = Instrument::new(
        Plate::flat(0.001, 0.008, 0.03),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .expect("a valid plate");
    let mut group = c.benchmark_group(format!("collision_query_{}tris_2x150", tris.len()));
    let backends: [Box<dyn RayBackend>; 2] = [
        Box::new(BruteForce::new(&tris, &rest).expect("a valid surface")),
        Box::new(Bvh::new(&tris, &rest).expect("a valid surface")),
    ];
    for mut backend in backends {
        let mut hist: Vec<History> = poses
            .iter()
            .map(|_| History::new(&inst, HistoryMode::ForceRate))
            .collect();
        let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
        let mut k = 0usize;
        group.bench_function(backend.method(), |b| {
            b.iter(|| {
                k += 1;
                let positions = if k % 2 == 0 { &rest } else { &bumped };
                backend.update_positions(positions);
                let q = ContactQuery {
                    positions,
                    rest: &rest,
                    triangles: &tris,
                    to_volume: &to_volume,
                    solved: None,
                };
                let mut tools: Vec<Tool<'_>> = hist
                    .iter_mut()
                    .zip(&poses)
                    .map(|(h, p)| Tool {
                        instrument: &inst,
                        pose: *p,
                        history: h,
                    })
                    .collect();
                detect_many(
                    backend.as_mut(),
                    &q,
                    &mut tools,
                    Stage::Deformation,
                    &DetectOptions::default(),
                    &mut ws,
                    &mut out,
                )
                .expect("a consistent surface");
                black_box(out.pairs.len())
            })
        });
    }
    group.finish();
}

criterion_group!(benches, query);
criterion_main!(benches);
