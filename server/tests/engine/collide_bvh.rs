//! The BVH backend answers exactly as the brute-force reference: same nearest
//! triangle behind and in front, same t, for random meshes, poses and
//! deformations, including exact ties (duplicated triangles) and rays through
//! vertices and edges.

use fissure_engine::collide::{
    BruteForce, Bvh, Instrument, NodeHits, NodeLayout, Plate, RayBackend, RayTest, RimNodes,
};
use fissure_engine::mesh::blocks;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn assert_same(a: &[NodeHits], b: &[NodeHits]) {
    assert_eq!(a.len(), b.len());
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        for (p, q) in [(x.behind, y.behind), (x.front, y.front)] {
            match (p, q) {
                (None, None) => {}
                (Some(p), Some(q)) => {
                    assert_eq!(p.triangle, q.triangle, "ray {i}: {x:?} vs {y:?}");
                    assert!((p.t - q.t).abs() <= 1e-12, "ray {i}: {x:?} vs {y:?}");
                }
                _ => panic!("ray {i}: {x:?} vs {y:?}"),
            }
        }
    }
}

/// A block surface, with duplicated triangles appended (exact ties) and a few
/// degenerate ones.
fn surface(n: usize, dup: usize) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let mesh = blocks::cuboid([0.03, 0.02, 0.025], [n, n + 1, n]);
    let s = mesh.boundary();
    let mut pos = Vec::new();
    s.gather(&mesh.nodes, &mut pos);
    let mut tris = s.triangles.clone();
    for k in 0..dup.min(tris.len()) {
        tris.push(tris[(k * 7) % s.triangles.len()]);
    }
    tris.push([0, 0, 1]);
    tris.push([2, 2, 2]);
    (pos, tris)
}

fn deform(pos: &mut [Point3<f64>], amp: f64, phase: f64) {
    for p in pos.iter_mut() {
        let (x, y, z) = (p.x, p.y, p.z);
        p.x += amp * (40.0 * y + phase).sin();
        p.y += amp * (35.0 * z - phase).cos();
        p.z += amp * (50.0 * x + 2.0 * phase).sin();
    }
}

fn cast(b: &mut dyn RayBackend, o: &[Point3<f64>], d: &[Vector3<f64>]) -> Vec<NodeHits> {
    let mut out = Vec::new();
    b.cast(o, d, &mut out);
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Instrument rays under random poses against a randomly deformed block,
    /// refitted over several deformation steps; 100 nodes a face make runs
    /// of parallel rays that the BVH casts as bundles (flat plates).
    #[test]
    fn bvh_equals_brute_force_on_instrument_rays(
        n in 2usize..6,
        dup in 0usize..20,
        amp in 0.0f64..2e-3,
        phase in 0.0f64..6.3,
        tx in 0.0f64..0.03, ty in 0.0f64..0.02, tz in 0.0f64..0.03,
        ax in -1.0f64..1.0, ay in -1.0f64..1.0, az in -1.0f64..1.0, angle in 0.0f64..3.2,
        curved in proptest::bool::ANY,
        per_face in prop_oneof![Just(30usize), Just(100usize)],
    ) {
        let (mut pos, tris) = surface(n, dup);
        let mut brute = BruteForce::new(&tris, &pos).unwrap();
        let mut bvh = Bvh::new(&tris, &pos).unwrap();
        let plate = if curved { Plate::curved(1e-3, 0.008, 0.02, 0.03) } else { Plate::flat(1e-3, 0.008, 0.02) };
        let inst = Instrument::new(plate, NodeLayout::WholeFace { per_face },
            Some(RimNodes { per_side: 4, tip: 3, tip_reach: 1e-3 })).unwrap();
        let axis = Vector3::new(ax, ay, az + 1e-3);
        let pose = Isometry3::from_parts(
            Translation3::new(tx, ty, tz),
            UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle),
        );
        let (mut o, mut d) = (Vec::new(), Vec::new());
        inst.place(&pose, &mut o, &mut d);
        for step in 0..3 {
            deform(&mut pos, amp, phase + step as f64);
            brute.update_positions(&pos);
            bvh.update_positions(&pos);
            let a = cast(&mut brute, &o, &d);
            let b = cast(&mut bvh, &o, &d);
            assert_same(&a, &b);
        }
    }

    /// Axis-aligned rays through grid vertices and edge midpoints of an
    /// undeformed block (exact ties of the tie rule), and random rays.
    #[test]
    fn bvh_equals_brute_force_on_vertex_and_edge_rays(
        n in 2usize..5,
        i in 0usize..5, j in 0usize..6, half in proptest::bool::ANY,
        sign in proptest::bool::ANY,
        rx in -1.0f64..1.0, ry in -1.0f64..1.0, rz in -1.0f64..1.0,
    ) {
        let (pos, tris) = surface(n, 5);
        let mut brute = BruteForce::new(&tris, &pos).unwrap();
        let mut bvh = Bvh::new(&tris, &pos).unwrap();
        let x = 0.03 * ((i.min(n) as f64) + if half { 0.5 } else { 0.0 }).min(n as f64) / n as f64;
        let y = 0.02 * (j.min(n + 1) as f64) / (n + 1) as f64;
        let s = if sign { 1.0 } else { -1.0 };
        let o = vec![Point3::new(x, y, 0.01), Point3::new(x, 0.01, 0.0125), Point3::new(0.015, y, 0.0125),
                     Point3::new(0.015, 0.01, 0.0125)];
        let d = vec![Vector3::z() * s, Vector3::y() * s, Vector3::x() * s,
                     Vector3::new(rx, ry, rz + 1e-3).normalize()];
        let a = cast(&mut brute, &o, &d);
        let b = cast(&mut bvh, &o, &d);
        assert_same(&a, &b);
        // A line through the inside of a closed block meets it behind and in
        // front, also exactly through vertices and edges of its faces (no crack).
        if x > 0.0 && x < 0.03 && y > 0.0 && y < 0.02 {
            prop_assert!(a[0].behind.is_some() && a[0].front.is_some());
        }
        prop_assert!(a[3].behind.is_some() && a[3].front.is_some());
    }
}

/// Möller–Trumbore backends agree too (same test on both sides).
#[test]
fn bvh_equals_brute_force_with_moller_trumbore() {
    let (mut pos, tris) = surface(4, 10);
    deform(&mut pos, 1e-3, 0.7);
    let mut brute = BruteForce::with_test(&tris, &pos, RayTest::MollerTrumbore).unwrap();
    let mut bvh = Bvh::with_test(&tris, &pos, RayTest::MollerTrumbore).unwrap();
    let inst = Instrument::new(
        Plate::flat(1e-3, 0.01, 0.02),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .unwrap();
    let pose = Isometry3::translation(0.015, 0.01, 0.005);
    let (mut o, mut d) = (Vec::new(), Vec::new());
    inst.place(&pose, &mut o, &mut d);
    assert_same(&cast(&mut brute, &o, &d), &cast(&mut bvh, &o, &d));
}

/// A refit after a large deformation and a rebuild give the same answers.
#[test]
fn refit_and_rebuild_agree_after_large_deformation() {
    let (mut pos, tris) = surface(5, 0);
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let mut rebuilt = bvh.clone();
    deform(&mut pos, 6e-3, 1.1);
    bvh.update_positions(&pos);
    rebuilt.rebuild(&pos);
    let mut brute = BruteForce::new(&tris, &pos).unwrap();
    let inst = Instrument::new(
        Plate::flat(1e-3, 0.01, 0.02),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .unwrap();
    let pose = Isometry3::translation(0.012, 0.01, 0.002);
    let (mut o, mut d) = (Vec::new(), Vec::new());
    inst.place(&pose, &mut o, &mut d);
    let r = cast(&mut brute, &o, &d);
    assert_same(&r, &cast(&mut bvh, &o, &d));
    assert_same(&r, &cast(&mut rebuilt, &o, &d));
}

/// Bad surfaces are refused with the offending index; positions of the wrong
/// length leave a backend answering no hits instead of panicking.
#[test]
fn bad_surfaces_are_reported() {
    let pos = vec![
        Point3::origin(),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
    ];
    assert!(Bvh::new(&[[0, 1, 3]], &pos).is_err());
    let mut nan = pos.clone();
    nan[1].x = f64::NAN;
    assert!(BruteForce::new(&[[0, 1, 2]], &nan).is_err());
    let mut bvh = Bvh::new(&[[0, 1, 2]], &pos).unwrap();
    bvh.update_positions(&pos[..2]);
    let out = cast(&mut bvh, &[Point3::new(0.2, 0.2, -1.0)], &[Vector3::z()]);
    assert_eq!(out, vec![NodeHits::default()]);
    bvh.update_positions(&pos);
    let out = cast(&mut bvh, &[Point3::new(0.2, 0.2, -1.0)], &[Vector3::z()]);
    assert_eq!(out[0].front.map(|h| h.triangle), Some(0));
}
