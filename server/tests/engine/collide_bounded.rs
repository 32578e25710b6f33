//! Bounded rays (`DetectOptions::bounded_rays`, the default) give exactly the
//! output of whole-line casts: same pairs, same cancelled pairs, same enforced
//! displacements, same renewed histories, step after step of random
//! trajectories that press two spatulas into a deformed block, cross it and
//! come back (deep penetration, so that the culling acts), with face nodes of
//! infinite and of finite reach, on the BVH and the brute force. Also checks
//! the ranged cast of each backend against the clipped whole-line answer.

use fissure_engine::collide::{
    BruteForce, Bvh, ContactOutput, ContactQuery, DetectOptions, History, HistoryMode, Instrument,
    NodeHits, NodeLayout, Plate, RayBackend, RayRange, RimNodes, Stage, Tool, Workspace,
    detect_many,
};
use fissure_engine::mesh::blocks;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

const MM: f64 = 1e-3;

struct Block {
    rest: Vec<Point3<f64>>,
    pos: Vec<Point3<f64>>,
    tris: Vec<[u32; 3]>,
    to_volume: Vec<u32>,
}

/// A 30 mm cube's surface, deformed by a smooth field of amplitude `amp`.
fn block(amp: f64) -> Block {
    let mesh = blocks::cube(0.03, 5);
    let s = mesh.boundary();
    let mut rest = Vec::new();
    s.gather(&mesh.nodes, &mut rest);
    let pos = rest
        .iter()
        .map(|p| {
            Point3::new(
                p.x + amp * (90.0 * p.y).sin(),
                p.y + amp * (70.0 * p.z).cos(),
                p.z + amp * (80.0 * p.x).sin(),
            )
        })
        .collect();
    Block {
        rest,
        pos,
        tris: s.triangles,
        to_volume: s.to_volume,
    }
}

/// A flat plate with `per_face` nodes a face (from 64 on, the BVH casts each
/// face's rays as one bundle) and rim nodes.
fn instrument(reach: Option<f64>, per_face: usize) -> Instrument {
    let mut inst = Instrument::new(
        Plate::flat(1.0 * MM, 8.0 * MM, 15.0 * MM),
        NodeLayout::WholeFace { per_face },
        Some(RimNodes {
            per_side: 4,
            tip: 3,
            tip_reach: 1.0 * MM,
        }),
    )
    .unwrap();
    if let Some(r) = reach {
        inst.cap_reach(r);
    }
    inst
}

/// Plate face B towards -z, centre at `(x, y, z)`, tilted by `tilt` about x.
fn pose(x: f64, y: f64, z: f64, tilt: f64) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
    let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), tilt);
    Isometry3::from_parts(Translation3::new(x, y, z), tilt * rot)
}

fn run(
    backend: &mut dyn RayBackend,
    b: &Block,
    inst: &Instrument,
    path: &[(Isometry3<f64>, Isometry3<f64>)],
    bounded: bool,
) -> Vec<(ContactOutput, Vec<bool>, Vec<bool>)> {
    let q = ContactQuery {
        positions: &b.pos,
        rest: &b.rest,
        triangles: &b.tris,
        to_volume: &b.to_volume,
        solved: None,
    };
    let opts = DetectOptions {
        bounded_rays: bounded,
        ..DetectOptions::default()
    };
    let mut h0 = History::new(inst, HistoryMode::ForceRate);
    let mut h1 = History::new(inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let mut steps = Vec::new();
    for (p0, p1) in path {
        let mut tools = [
            Tool {
                instrument: inst,
                pose: *p0,
                history: &mut h0,
            },
            Tool {
                instrument: inst,
                pose: *p1,
                history: &mut h1,
            },
        ];
        detect_many(
            backend,
            &q,
            &mut tools,
            Stage::Force,
            &opts,
            &mut ws,
            &mut out,
        )
        .unwrap();
        steps.push((out.clone(), h0.flags().to_vec(), h1.flags().to_vec()));
    }
    steps
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, ..ProptestConfig::default() })]

    #[test]
    fn bounded_rays_give_the_whole_line_output(
        amp in 0.0f64..1.0e-3,
        x0 in 0.004f64..0.02, y0 in 0.004f64..0.026,
        dx in -0.01f64..0.01, dy in -0.01f64..0.01,
        tilt in -0.4f64..0.4,
        step in 0.2e-3f64..6e-3,
        reach in proptest::option::of(0.5e-3f64..12e-3),
        use_brute in proptest::bool::ANY,
        per_face in prop_oneof![Just(24usize), Just(80usize)],
    ) {
        let b = block(amp);
        let inst = instrument(reach, per_face);
        // Down through the top face (z = 30 mm), past the bottom, and back.
        let mut path = Vec::new();
        let mut z = 0.032;
        let mut k = 0;
        while z > -0.004 {
            let f = k as f64 * 0.05;
            path.push((pose(x0 + dx * f, y0, z, tilt), pose(x0, y0 + dy * f, z + 0.5 * step, -tilt)));
            z -= step;
            k += 1;
        }
        let back: Vec<_> = path.iter().rev().cloned().collect();
        path.extend(back);
        let mut backend: Box<dyn RayBackend> = if use_brute {
            Box::new(BruteForce::new(&b.tris, &b.pos).unwrap())
        } else {
            Box::new(Bvh::new(&b.tris, &b.pos).unwrap())
        };
        let whole = run(backend.as_mut(), &b, &inst, &path, false);
        let bounded = run(backend.as_mut(), &b, &inst, &path, true);
        for (s, (w, c)) in whole.iter().zip(&bounded).enumerate() {
            prop_assert_eq!(&w.0, &c.0, "step {}", s);
            prop_assert_eq!(&w.1, &c.1, "history 0, step {}", s);
            prop_assert_eq!(&w.2, &c.2, "history 1, step {}", s);
        }
        // Not vacuous: the trajectory makes contact.
        prop_assert!(whole.iter().any(|w| !w.0.pairs.is_empty()));
    }

    /// A ranged cast is the whole-line answer clipped to the range, on both
    /// CPU backends, for random rays and ranges (including none on a side).
    #[test]
    fn ranged_cast_is_the_clipped_whole_line_cast(
        amp in 0.0f64..1.0e-3,
        seed in 0u64..1000,
        behind in -1.0e-3f64..0.04,
        front in -1.0e-3f64..0.04,
    ) {
        let b = block(amp);
        let mut bvh = Bvh::new(&b.tris, &b.pos).unwrap();
        let mut brute = BruteForce::new(&b.tris, &b.pos).unwrap();
        let mut o = Vec::new();
        let mut d = Vec::new();
        let mut r = Vec::new();
        let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut next = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for i in 0..64 {
            o.push(Point3::new(0.04 * next() - 0.005, 0.04 * next() - 0.005, 0.04 * next() - 0.005));
            d.push(Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5 + 1e-3).normalize());
            let scale = (i % 4) as f64 / 3.0;
            r.push(RayRange { behind: behind * scale, front: front * (1.0 - scale) });
        }
        let mut whole = Vec::new();
        brute.cast(&o, &d, &mut whole);
        let clipped: Vec<NodeHits> = whole.iter().zip(&r).map(|(h, r)| r.clip(*h)).collect();
        for backend in [&mut bvh as &mut dyn RayBackend, &mut brute] {
            let mut got = Vec::new();
            backend.cast_ranged(&o, &d, &r, &mut got);
            prop_assert_eq!(&got, &clipped, "{}", backend.method());
        }
    }
}

/// Rays of one batch clustered in a small region (as a spatula's are), so
/// that the BVH starts them below the root: the ranged answers still equal the
/// clipped whole-line answers, with ranges ending exactly at a hit (that hit
/// is kept), ranges just short of it (dropped), and unbounded rays mixed in.
#[test]
fn clustered_ranged_rays_match_the_clipped_whole_line_cast() {
    let mesh = blocks::cube(0.03, 16);
    let s = mesh.boundary();
    let mut pos = Vec::new();
    s.gather(&mesh.nodes, &mut pos);
    for p in pos.iter_mut() {
        p.x += 0.3 * MM * (90.0 * p.y).sin();
        p.z += 0.3 * MM * (80.0 * p.x).sin();
    }
    let tris = s.triangles;
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let mut brute = BruteForce::new(&tris, &pos).unwrap();
    let mut x = 12345u64;
    let mut next = || {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut exact_kept, mut short_dropped) = (0, 0);
    for batch in 0..200 {
        // A cluster about a point near the cube's surface, up to 5 mm across.
        let c = Point3::new(
            0.03 * next(),
            0.03 * next(),
            if batch % 2 == 0 { 0.03 } else { 0.0 },
        );
        let spread = 5.0 * MM * next();
        let axis = Vector3::new(next() - 0.5, next() - 0.5, 2.0 * next() - 1.0).normalize();
        let (mut o, mut d) = (Vec::new(), Vec::new());
        for _ in 0..40 {
            o.push(c + Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5) * spread);
            d.push(
                (axis + 0.2 * Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5)).normalize(),
            );
        }
        let mut whole = Vec::new();
        brute.cast(&o, &d, &mut whole);
        let r: Vec<RayRange> = whole
            .iter()
            .enumerate()
            .map(|(i, h)| match i % 5 {
                // Ends exactly at the hits.
                0 => RayRange {
                    behind: h.behind.map_or(2.0 * MM, |h| -h.t),
                    front: h.front.map_or(2.0 * MM, |h| h.t),
                },
                // Just short of them.
                1 => RayRange {
                    behind: h.behind.map_or(-1.0, |h| (-h.t) * (1.0 - 1e-12) - 1e-18),
                    front: h.front.map_or(-1.0, |h| h.t * (1.0 - 1e-12)),
                },
                2 => RayRange::LINE,
                3 => RayRange {
                    behind: 3.0 * MM,
                    front: -1.0,
                },
                _ => RayRange {
                    behind: 10.0 * MM,
                    front: f64::INFINITY,
                },
            })
            .collect();
        let clipped: Vec<NodeHits> = whole.iter().zip(&r).map(|(h, r)| r.clip(*h)).collect();
        for (i, (w, c)) in whole.iter().zip(&clipped).enumerate() {
            if i % 5 == 0 && w.behind.is_some() {
                assert!(c.behind.is_some());
                exact_kept += 1;
            }
            if i % 5 == 1 && w.behind.is_some_and(|h| h.t < 0.0) {
                assert!(c.behind.is_none());
                short_dropped += 1;
            }
        }
        for backend in [&mut bvh as &mut dyn RayBackend, &mut brute] {
            let mut got = Vec::new();
            backend.cast_ranged(&o, &d, &r, &mut got);
            assert_eq!(got, clipped, "{}, batch {batch}", backend.method());
        }
        let mut seq = Vec::new();
        bvh.cast_ranged_with(&o, &d, &r, faer::Par::Seq, &mut seq);
        assert_eq!(seq, clipped, "sequential, batch {batch}");
    }
    // Not vacuous: the boundary cases occurred.
    assert!(
        exact_kept > 100 && short_dropped > 100,
        "{exact_kept} {short_dropped}"
    );
}

/// A deep push through the block in 2 mm steps culls pairs (the far face's
/// pairs of the paper's Figure 6); bounded rays cancel exactly the same ones.
#[test]
fn bounded_rays_cull_the_same_pairs_in_deep_penetration() {
    let b = block(0.0);
    // Unlimited reach, and reaches shorter than the block: flagged nodes'
    // front hits on the far side then lie beyond reach, and the second pass
    // must find those that are pair triangles (20 mm, tilted, fails without
    // it).
    for reach in [
        None,
        Some(3.0 * MM),
        Some(6.0 * MM),
        Some(12.0 * MM),
        Some(20.0 * MM),
    ] {
        let inst = instrument(reach, 24);
        for tilt in [0.0, 0.2, 0.5] {
            let path: Vec<_> = (0..30)
                .map(|k| {
                    let z = 0.031 - 1.2e-3 * k as f64;
                    (pose(0.012, 0.01, z, tilt), pose(0.012, 0.02, z, 0.2 - tilt))
                })
                .collect();
            let mut bvh = Bvh::new(&b.tris, &b.pos).unwrap();
            let whole = run(&mut bvh, &b, &inst, &path, false);
            let bounded = run(&mut bvh, &b, &inst, &path, true);
            let cancelled: usize = whole.iter().map(|w| w.0.cancelled.len()).sum();
            if reach.is_none_or(|r| r > 0.015) {
                assert!(
                    cancelled > 0,
                    "reach {reach:?}: the push must trigger the culling"
                );
            }
            for (s, (w, c)) in whole.iter().zip(&bounded).enumerate() {
                assert_eq!(w, c, "reach {reach:?}, tilt {tilt}, step {s}");
            }
        }
    }
}
