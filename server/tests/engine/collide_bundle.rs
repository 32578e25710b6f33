//! The bundled traversal (runs of at least 64 parallel rays) gives the
//! per-ray BVH answers and the clipped brute-force answers bit for bit:
//! grids of parallel rays aligned with the mesh lattice (through vertices and
//! edges) and offset from it, axis-aligned and tilted, on a deformed cube;
//! bounded rays, whole lines and rays bounded on one side only, from grids
//! wide and narrow against the distance to the nearest hit (a narrow bundle
//! clips its whole lines short of every hit, and the rays are cast again).

use fissure_engine::collide::rays::bvh::Traversal;
use fissure_engine::collide::{BruteForce, Bvh, NodeHits, RayBackend, RayRange};
use fissure_engine::mesh::blocks;
use nalgebra::{Point3, Vector3};

/// The boundary of a 30 mm cube of 8 cells a side, deformed by `f`.
fn surface(f: impl Fn(&mut Point3<f64>)) -> (Bvh, BruteForce) {
    let mesh = blocks::cube(0.03, 8);
    let s = mesh.boundary();
    let mut pos = Vec::new();
    s.gather(&mesh.nodes, &mut pos);
    pos.iter_mut().for_each(f);
    let tris = s.triangles;
    (
        Bvh::new(&tris, &pos).unwrap(),
        BruteForce::new(&tris, &pos).unwrap(),
    )
}

/// A 12 x 10 grid of origins at height `z`, `spacing` apart, shifted by
/// `offset` (fractions of the spacing) from `corner`.
fn grid(corner: [f64; 2], spacing: f64, offset: [f64; 2], z: f64) -> Vec<Point3<f64>> {
    let mut o = Vec::new();
    for i in 0..12 {
        for j in 0..10 {
            o.push(Point3::new(
                corner[0] + (i as f64 + offset[0]) * spacing,
                corner[1] + (j as f64 + offset[1]) * spacing,
                z,
            ));
        }
    }
    o
}

/// Per-ray and bundled, parallel and sequential, against the brute force's
/// whole-line answers clipped to `r`; returns whether any ray hit.
fn check_all_traversals(
    bvh: &mut Bvh,
    brute: &mut BruteForce,
    o: &[Point3<f64>],
    d: &[Vector3<f64>],
    r: &[RayRange],
    what: &str,
) -> bool {
    let mut whole = Vec::new();
    brute.cast(o, d, &mut whole);
    let clipped: Vec<NodeHits> = whole.iter().zip(r).map(|(h, r)| r.clip(*h)).collect();
    for t in [Traversal::PerRay, Traversal::Bundled] {
        bvh.set_traversal(t);
        let mut got = Vec::new();
        bvh.cast_ranged(o, d, r, &mut got);
        assert_eq!(got, clipped, "{t:?} {what}");
        bvh.cast_ranged_with(o, d, r, faer::Par::Seq, &mut got);
        assert_eq!(got, clipped, "seq {t:?} {what}");
    }
    clipped
        .iter()
        .any(|c| c.front.is_some() || c.behind.is_some())
}

#[test]
fn bundled_cast_equals_per_ray_and_brute_force() {
    for amp in [0.0, 0.3e-3] {
        let (mut bvh, mut brute) = surface(|p| {
            p.x += amp * (90.0 * p.y).sin();
            p.z += amp * (80.0 * p.x).sin();
        });
        let h = 0.03 / 8.0;
        for (offset, dir) in [
            ([0.0, 0.0], Vector3::z()),
            ([0.372, 0.618], Vector3::z()),
            ([0.5, 0.0], -Vector3::z()),
            ([0.372, 0.618], Vector3::new(0.1, -0.2, 1.0).normalize()),
            ([0.0, 0.0], Vector3::new(1.0, 1.0, 1.0).normalize()),
        ] {
            let o = grid([0.0, 0.0], h, offset, 0.015);
            let d = vec![dir; o.len()];
            let r: Vec<RayRange> = (0..o.len())
                .map(|i| RayRange {
                    behind: 0.02 * (i % 3) as f64 / 2.0,
                    front: 0.02 - 0.005 * (i % 4) as f64,
                })
                .collect();
            let what = format!("amp {amp} {offset:?} {dir:?}");
            assert!(check_all_traversals(
                &mut bvh, &mut brute, &o, &d, &r, &what
            ));
        }
    }
}

/// Whole lines, one-sided bounds and bounds past every hit, from a grid as
/// wide as the cube (every hit within the bundle's reach) and from a narrow
/// one (2.2 x 1.8 mm: every whole line is clipped short of its hits and cast
/// again), inside and outside the block.
#[test]
fn bundled_whole_lines_equal_per_ray_and_brute_force() {
    let (mut bvh, mut brute) = surface(|p| p.y += 0.2e-3 * (70.0 * p.z).sin());
    let inf = f64::INFINITY;
    for spacing in [0.03 / 8.0, 0.2e-3] {
        for (z, dir) in [
            (0.015, Vector3::z()),
            // The narrow grid's reach is 2 x 2.2 mm: the top face is 4.5 mm
            // in front, just past it (a recast that skipped too much would
            // miss it).
            (0.0255, Vector3::z()),
            (0.05, -Vector3::z()),
            (0.012, Vector3::new(0.2, 0.1, 1.0).normalize()),
        ] {
            let o = grid([0.004, 0.003], spacing, [0.372, 0.618], z);
            let d = vec![dir; o.len()];
            let what = format!("spacing {spacing} z {z} {dir:?}");
            let lines = vec![RayRange::LINE; o.len()];
            assert!(check_all_traversals(
                &mut bvh, &mut brute, &o, &d, &lines, &what
            ));
            let mixed: Vec<RayRange> = (0..o.len())
                .map(|i| match i % 8 {
                    0 => RayRange {
                        behind: inf,
                        front: 0.004,
                    },
                    1 => RayRange {
                        behind: 0.004,
                        front: inf,
                    },
                    2 => RayRange {
                        behind: -1.0,
                        front: inf,
                    },
                    3 => RayRange {
                        behind: inf,
                        front: -1.0,
                    },
                    // Nowhere on one side, however it is written.
                    5 => RayRange {
                        behind: -inf,
                        front: inf,
                    },
                    6 => RayRange {
                        behind: inf,
                        front: f64::NAN,
                    },
                    _ => RayRange {
                        behind: 0.1,
                        front: 0.1,
                    },
                })
                .collect();
            assert!(check_all_traversals(
                &mut bvh, &mut brute, &o, &d, &mixed, &what
            ));
            // No ranges at all: whole lines.
            let mut whole = Vec::new();
            brute.cast(&o, &d, &mut whole);
            for t in [Traversal::PerRay, Traversal::Bundled] {
                bvh.set_traversal(t);
                let mut got = Vec::new();
                bvh.cast(&o, &d, &mut got);
                assert_eq!(got, whole, "cast {t:?} {what}");
            }
        }
    }
}
