//! The bundled traversal (runs of at least 64 parallel bounded rays) gives
//! the per-ray BVH answers and the clipped brute-force answers bit for bit:
//! grids of parallel rays aligned with the mesh lattice (through vertices and
//! edges) and offset from it, axis-aligned and tilted, on a deformed cube.

use fissure_server::collide::bvh::Traversal;
use fissure_server::collide::{BruteForce, Bvh, NodeHits, RayBackend, RayRange};
use fissure_server::mesh::blocks;
use nalgebra::{Point3, Vector3};

#[test]
fn bundled_cast_equals_per_ray_and_brute_force() {
    for amp in [0.0, 0.3e-3] {
        let mesh = blocks::cube(0.03, 8);
        let s = mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&mesh.nodes, &mut pos);
        for p in pos.iter_mut() {
            p.x += amp * (90.0 * p.y).sin();
            p.z += amp * (80.0 * p.x).sin();
        }
        let tris = s.triangles;
        let mut bvh = Bvh::new(&tris, &pos).unwrap();
        let mut brute = BruteForce::new(&tris, &pos).unwrap();
        let h = 0.03 / 8.0;
        for (offset, dir) in [
            ([0.0, 0.0], Vector3::z()),
            ([0.372, 0.618], Vector3::z()),
            ([0.5, 0.0], -Vector3::z()),
            ([0.372, 0.618], Vector3::new(0.1, -0.2, 1.0).normalize()),
            ([0.0, 0.0], Vector3::new(1.0, 1.0, 1.0).normalize()),
        ] {
            let mut o = Vec::new();
            for i in 0..12 {
                for j in 0..10 {
                    o.push(Point3::new(
                        (i as f64 + offset[0]) * h,
                        (j as f64 + offset[1]) * h,
                        0.015,
                    ));
                }
            }
            let d = vec![dir; o.len()];
            let r: Vec<RayRange> = (0..o.len())
                .map(|i| RayRange {
                    behind: 0.02 * (i % 3) as f64 / 2.0,
                    front: 0.02 - 0.005 * (i % 4) as f64,
                })
                .collect();
            let mut whole = Vec::new();
            brute.cast(&o, &d, &mut whole);
            let clipped: Vec<NodeHits> = whole.iter().zip(&r).map(|(h, r)| r.clip(*h)).collect();
            assert!(
                clipped
                    .iter()
                    .any(|c| c.front.is_some() || c.behind.is_some())
            );
            for t in [Traversal::PerRay, Traversal::Bundled] {
                bvh.set_traversal(t);
                let mut got = Vec::new();
                bvh.cast_ranged(&o, &d, &r, &mut got);
                assert_eq!(got, clipped, "{t:?} {offset:?} {dir:?}");
                bvh.cast_ranged_with(&o, &d, &r, faer::Par::Seq, &mut got);
                assert_eq!(got, clipped, "seq {t:?} {offset:?} {dir:?}");
            }
        }
    }
}
