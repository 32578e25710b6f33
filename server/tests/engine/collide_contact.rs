//! Contact-stage rules: the conflict rule for vertices claimed by several
//! pairs, the A2 normal test, reach of rim nodes, errors, and no allocation in
//! steady state.

use fissure_engine::collide::{
    BruteForce, Bvh, ContactError, ContactOutput, ContactQuery, ContactRule, DetectOptions, FaceId,
    History, HistoryMode, Instrument, NodeKind, NodeLayout, Plate, RimNodes, Stage, Tool,
    Workspace, detect, detect_many,
};
use fissure_engine::mesh::blocks;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;

const MM: f64 = 1e-3;

fn block() -> (Vec<Point3<f64>>, Vec<[u32; 3]>, Vec<u32>) {
    let mesh = blocks::cube(0.03, 6);
    let s = mesh.boundary();
    let mut pos = Vec::new();
    s.gather(&mesh.nodes, &mut pos);
    (pos, s.triangles, s.to_volume)
}

/// Plate lying flat on the top (z = 30 mm), face B (normal -z) pressing down so
/// that it is `depth` below the top; length along +x from `x0`.
fn press(x0: f64, depth: f64, h: f64) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
    Isometry3::from_parts(Translation3::new(x0, 0.0151, 0.03 - depth + 0.5 * h), rot)
}

/// Two spatulas press the top at different depths over an overlapping area:
/// every vertex claimed by both ends on the deeper face's plane, and is
/// attributed to that spatula; vertices claimed by one keep its projection.
#[test]
fn conflicting_vertices_take_the_deepest_projection() {
    let (pos, tris, to_volume) = block();
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let h = 1.0 * MM;
    let inst = Instrument::new(
        Plate::flat(h, 8.0 * MM, 15.0 * MM),
        NodeLayout::WholeFace { per_face: 60 },
        None,
    )
    .unwrap();
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let mut hs = [
        History::new(&inst, HistoryMode::ForceRate),
        History::new(&inst, HistoryMode::ForceRate),
    ];
    // Spatula 0 shallow (0.3 mm) from x = 5 mm, spatula 1 deep (0.7 mm) from x = 12 mm.
    let depths = [0.3 * MM, 0.7 * MM];
    let [h0, h1] = &mut hs;
    let mut tools = [
        Tool {
            instrument: &inst,
            pose: press(0.005, depths[0], h),
            history: h0,
        },
        Tool {
            instrument: &inst,
            pose: press(0.012, depths[1], h),
            history: h1,
        },
    ];
    detect_many(
        &mut bvh,
        &q,
        &mut tools,
        Stage::Deformation,
        &DetectOptions::paper(),
        &mut ws,
        &mut out,
    )
    .unwrap();
    // Which vertices each spatula's pairs claim.
    let mut claimed: HashMap<u32, [bool; 2]> = HashMap::new();
    for p in &out.pairs {
        assert_eq!(inst.nodes[p.node as usize].kind, NodeKind::FaceB);
        for v in tris[p.triangle as usize] {
            claimed.entry(v).or_default()[p.instrument as usize] = true;
        }
    }
    let both = claimed.values().filter(|c| c[0] && c[1]).count();
    assert!(both >= 3, "the spatulas share vertices ({both})");
    assert_eq!(
        out.enforced.len(),
        claimed.len(),
        "one condition per vertex"
    );
    for e in &out.enforced {
        let c = claimed[&e.surface_vertex];
        let winner = if c[1] { 1 } else { 0 };
        assert_eq!(e.instrument, winner, "{e:?}");
        let z = pos[e.surface_vertex as usize].z + e.displacement.z;
        assert!(
            (z - (0.03 - depths[winner as usize])).abs() < 1e-12,
            "{e:?}"
        );
        assert!(e.displacement.x.abs() < 1e-15 && e.displacement.y.abs() < 1e-15);
        assert!((e.depth - depths[winner as usize]).abs() < 1e-12);
    }
}

/// A2: a triangle behind a face whose normal points the same way as the face
/// normal gives no pair (face A above the top looks down onto the top face,
/// whose normal is +z like face A's).
#[test]
fn same_facing_triangle_gives_no_pair() {
    let (pos, tris, to_volume) = block();
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let h = 1.0 * MM;
    let inst = Instrument::new(
        Plate::flat(h, 8.0 * MM, 15.0 * MM),
        NodeLayout::WholeFace { per_face: 60 },
        None,
    )
    .unwrap();
    let mut brute = BruteForce::new(&tris, &pos).unwrap();
    let mut hist = History::new(&inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    detect(
        &mut brute,
        &q,
        &inst,
        &press(0.005, 0.3 * MM, h),
        &mut hist,
        Stage::Force,
        &DetectOptions::default(),
        &mut ws,
        &mut out,
    )
    .unwrap();
    // Face A nodes all see the top face behind them, with an agreeing normal.
    for i in 0..60 {
        let b = ws.hits[i].behind.expect("the top face is behind face A");
        assert!((b.t + 0.7 * MM).abs() < 1e-12);
    }
    assert!(out.pairs.iter().all(|p| p.node >= 60));
    assert_eq!(out.pairs.len(), 60);
}

/// Rim nodes pair only within their reach: a side rim node pushed 1 mm into a
/// wall pairs, the same node whose nearest triangle behind lies beyond half the
/// width does not.
#[test]
fn rim_nodes_pair_within_reach() {
    let (pos, tris, to_volume) = block();
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let inst = Instrument::new(
        Plate::flat(1.0 * MM, 8.0 * MM, 15.0 * MM),
        NodeLayout::WholeFace { per_face: 6 },
        Some(RimNodes {
            per_side: 5,
            tip: 0,
            tip_reach: 1.0 * MM,
        }),
    )
    .unwrap();
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    // Plate vertical, tip down; the instrument's -y rim maps to world +y.
    // Centre y = -3 mm puts that rim 1 mm into the wall y = 0 (reach 4 mm);
    // centre y = +1 mm puts it 5 mm in, beyond its reach.
    let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    for (centre_y, expect) in [(-3.0 * MM, true), (1.0 * MM, false)] {
        let mut hist = History::new(&inst, HistoryMode::ForceRate);
        let pose = Isometry3::from_parts(Translation3::new(0.015, centre_y, 0.035), rot);
        detect(
            &mut bvh,
            &q,
            &inst,
            &pose,
            &mut hist,
            Stage::Force,
            &DetectOptions::paper(),
            &mut ws,
            &mut out,
        )
        .unwrap();
        let rim = out
            .pairs
            .iter()
            .filter(|p| inst.nodes[p.node as usize].kind == NodeKind::RimMinusY)
            .count();
        assert_eq!(rim > 0, expect, "centre y {centre_y}: {:?}", out.pairs);
        if expect {
            assert_eq!(rim, out.pairs.len(), "only the rim touches");
            for e in &out.enforced {
                let y = pos[e.surface_vertex as usize].y + e.displacement.y;
                assert!((y - 1.0 * MM).abs() < 1e-12, "{e:?}");
            }
        }
    }
}

/// Inconsistent input is reported, not a panic, and leaves the history alone.
#[test]
fn bad_queries_are_reported() {
    let (pos, tris, to_volume) = block();
    let inst = Instrument::new(
        Plate::flat(1e-3, 8e-3, 15e-3),
        NodeLayout::WholeFace { per_face: 6 },
        None,
    )
    .unwrap();
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let mut hist = History::new(&inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let short = ContactQuery {
        positions: &pos,
        rest: &pos[1..],
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let err = detect(
        &mut bvh,
        &short,
        &inst,
        &press(0.005, 3e-4, 1e-3),
        &mut hist,
        Stage::Force,
        &DetectOptions::default(),
        &mut ws,
        &mut out,
    );
    assert!(matches!(
        err,
        Err(ContactError::LengthMismatch { what: "rest", .. })
    ));
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let mut bad = press(0.005, 3e-4, 1e-3);
    bad.translation.vector.x = f64::NAN;
    let err = detect(
        &mut bvh,
        &q,
        &inst,
        &bad,
        &mut hist,
        Stage::Force,
        &DetectOptions::default(),
        &mut ws,
        &mut out,
    );
    assert!(matches!(
        err,
        Err(ContactError::NonFinitePose { instrument: 0 })
    ));
    assert_eq!(hist.active(), 0);
    assert!(out.pairs.is_empty());
}

/// Repeated queries reuse every buffer: no reallocation in steady state.
#[test]
fn steady_state_does_not_reallocate() {
    let (pos, tris, to_volume) = block();
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let inst = Instrument::new(
        Plate::flat(1e-3, 8e-3, 15e-3),
        NodeLayout::WholeFace { per_face: 60 },
        None,
    )
    .unwrap();
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    let mut hist = History::new(&inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let opts = DetectOptions::default();
    let pose = press(0.005, 3e-4, 1e-3);
    detect(
        &mut bvh,
        &q,
        &inst,
        &pose,
        &mut hist,
        Stage::Force,
        &opts,
        &mut ws,
        &mut out,
    )
    .unwrap();
    let ptrs = |ws: &Workspace, out: &ContactOutput| {
        (
            ws.origins.as_ptr(),
            ws.dirs.as_ptr(),
            ws.hits.as_ptr(),
            out.pairs.as_ptr(),
            out.enforced.as_ptr(),
        )
    };
    let before = ptrs(&ws, &out);
    assert!(!out.pairs.is_empty());
    for k in 0..20 {
        let pose = press(0.005 + 1e-4 * k as f64, 3e-4, 1e-3);
        detect(
            &mut bvh,
            &q,
            &inst,
            &pose,
            &mut hist,
            Stage::Force,
            &opts,
            &mut ws,
            &mut out,
        )
        .unwrap();
        assert_eq!(ptrs(&ws, &out), before);
    }
}

/// A large tilted triangle crosses face B's plane: one vertex 1 mm behind the
/// face, under it; two 3 mm in front and 50 mm beyond its outline. The
/// paper's rule projects all three onto the face plane (the two in front
/// are pulled 3 mm towards the plate); the Signorini rule names only the
/// vertex the face covers, with the face's normal and a negative gap.
#[test]
fn signorini_rule_names_only_covered_vertices_the_paper_rule_projects_all() {
    let inst = Instrument::new(
        Plate::flat(1.0 * MM, 8.0 * MM, 15.0 * MM),
        NodeLayout::WholeFace { per_face: 60 },
        None,
    )
    .unwrap();
    let pose = press(0.0, 0.0, 1.0 * MM);
    let (mut o, mut d) = (Vec::new(), Vec::new());
    inst.place(&pose, &mut o, &mut d);
    let face_b: Vec<Point3<f64>> = inst
        .nodes
        .iter()
        .zip(&o)
        .filter(|(n, _)| n.kind == NodeKind::FaceB)
        .map(|(_, p)| *p)
        .collect();
    let c = face_b.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / face_b.len() as f64;
    let z0 = c.z;
    // Counter-clockwise seen from +z: outward normal up, against face B's -z.
    let pos = vec![
        Point3::new(c.x, c.y, z0 + 1.0 * MM),
        Point3::new(c.x + 0.05, c.y - 0.05, z0 - 3.0 * MM),
        Point3::new(c.x + 0.05, c.y + 0.05, z0 - 3.0 * MM),
    ];
    let tris = vec![[0u32, 1, 2]];
    let to_volume = vec![0u32, 1, 2];
    let q = ContactQuery {
        positions: &pos,
        rest: &pos,
        triangles: &tris,
        to_volume: &to_volume,
        solved: None,
    };
    let mut bvh = Bvh::new(&tris, &pos).unwrap();
    for opts in [DetectOptions::paper(), DetectOptions::default()] {
        let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
        let mut hist = History::new(&inst, HistoryMode::ForceRate);
        detect(
            &mut bvh,
            &q,
            &inst,
            &pose,
            &mut hist,
            Stage::Force,
            &opts,
            &mut ws,
            &mut out,
        )
        .unwrap();
        assert!(!out.pairs.is_empty(), "face B meets the triangle");
        if opts.rule == ContactRule::Paper {
            let by_vertex: HashMap<u32, Vector3<f64>> = out
                .enforced
                .iter()
                .map(|e| (e.surface_vertex, e.displacement))
                .collect();
            assert_eq!(by_vertex.len(), 3, "{by_vertex:?}");
            assert!((by_vertex[&0].z + 1.0 * MM).abs() < 1e-12, "{by_vertex:?}");
            for v in [1, 2] {
                assert!((by_vertex[&v].z - 3.0 * MM).abs() < 1e-12, "{by_vertex:?}");
            }
        } else {
            assert!(out.enforced.is_empty());
            assert_eq!(out.candidates.len(), 1, "{:?}", out.candidates);
            let cand = out.candidates[0];
            assert_eq!(cand.surface_vertex, 0);
            assert_eq!(cand.face, FaceId::B);
            assert!((cand.normal + Vector3::z()).norm() < 1e-12, "{cand:?}");
            assert!((cand.gap_now_m + 1.0 * MM).abs() < 1e-12, "{cand:?}");
        }
    }
}
