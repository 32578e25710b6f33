//! The paper's situations (Fukuhara et al. 2014) on the V and U blocks, a wall
//! and a narrow slot standing in for a fissure.
//!
//! The FEM is not part of these tests: the surface stays at rest while the
//! spatulas move, exactly as the 1 kHz force loop sees the last published
//! surface between two deformation steps. The fissure is a block with a slot
//! 2 mm wide and 20 mm deep (a `cuboid` whose middle column of cells is mapped
//! to 2 mm and whose tetrahedra above z = 10 mm are removed); a phantom-brain
//! variant belongs with the phantom.

use fissure_engine::collide::{
    Bvh, ContactOutput, ContactQuery, DetectOptions, History, HistoryMode, Instrument, NodeKind,
    NodeLayout, Pair, Plate, Stage, Tool, Workspace, detect, detect_many,
};
use fissure_engine::mesh::{TetMesh, blocks};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::PI;

const MM: f64 = 1e-3;

struct Surface {
    pos: Vec<Point3<f64>>,
    tris: Vec<[u32; 3]>,
    to_volume: Vec<u32>,
}

impl Surface {
    fn new(mesh: &TetMesh) -> Self {
        let s = mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&mesh.nodes, &mut pos);
        Self {
            pos,
            tris: s.triangles,
            to_volume: s.to_volume,
        }
    }

    fn query(&self) -> ContactQuery<'_> {
        ContactQuery {
            positions: &self.pos,
            rest: &self.pos,
            triangles: &self.tris,
            to_volume: &self.to_volume,
            solved: None,
        }
    }

    fn verts(&self, p: &Pair) -> [Point3<f64>; 3] {
        self.tris[p.triangle as usize].map(|v| self.pos[v as usize])
    }

    fn backend(&self) -> Bvh {
        Bvh::new(&self.tris, &self.pos).unwrap()
    }
}

/// Tip pointing down (-z), face A normal +x, width along -y; handle point at `h`.
fn down(h: Point3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(h.coords),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI),
    )
}

fn kind(inst: &Instrument, p: &Pair) -> NodeKind {
    inst.nodes[p.node as usize].kind
}

/// (a) A spatula moved down into the V valley pushes both walls with both faces;
/// every surviving pair holds a groove-wall triangle on the side its face looks
/// at, and the enforced displacements push the walls apart.
#[test]
fn v_valley_both_faces_push_both_walls() {
    let mesh = blocks::v_valley();
    let surf = Surface::new(&mesh);
    let mut bvh = surf.backend();
    let inst = Instrument::new(
        Plate::flat(2.0 * MM, 10.0 * MM, 40.0 * MM),
        NodeLayout::Tip {
            per_face: 60,
            fraction: 0.15,
        },
        None,
    )
    .unwrap();
    let mut hist = History::new(&inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let on_groove = |p: &Point3<f64>| {
        let top = 0.03 - 0.02 * (1.0 - ((p.x - 0.03).abs() / 0.012).min(1.0));
        (p.x - 0.03).abs() <= 0.012 + 1e-12 && (p.z - top).abs() < 1e-12
    };
    let steps = 58;
    for k in 0..=steps {
        let tip = 16.0 * MM - (16.0 - 10.2) * MM * k as f64 / steps as f64;
        let pose = down(Point3::new(0.03, 0.015, tip + 0.04));
        detect(
            &mut bvh,
            &surf.query(),
            &inst,
            &pose,
            &mut hist,
            Stage::Force,
            &DetectOptions::paper(),
            &mut ws,
            &mut out,
        )
        .unwrap();
        for p in &out.pairs {
            let v = surf.verts(p);
            assert!(
                v.iter().all(on_groove),
                "step {k}: pair off the groove {p:?} {v:?}"
            );
            match kind(&inst, p) {
                NodeKind::FaceA => assert!(
                    v.iter().all(|q| q.x >= 0.03 - 1e-12),
                    "A pair on the left wall"
                ),
                NodeKind::FaceB => assert!(
                    v.iter().all(|q| q.x <= 0.03 + 1e-12),
                    "B pair on the right wall"
                ),
                k => panic!("no rim nodes here: {k:?}"),
            }
        }
    }
    let a = out
        .pairs
        .iter()
        .filter(|p| kind(&inst, p) == NodeKind::FaceA)
        .count();
    let b = out
        .pairs
        .iter()
        .filter(|p| kind(&inst, p) == NodeKind::FaceB)
        .count();
    assert!(a >= 10 && b >= 10, "both faces in contact: A {a}, B {b}");
    assert!(
        out.cancelled.is_empty(),
        "nothing to cull in a gentle insertion"
    );
    // Every vertex of a paired triangle goes onto its face's plane
    // (x = 30 +- 1 mm); penetrating vertices move outward, the deepest 1 mm.
    for e in &out.enforced {
        let rest = surf.pos[e.surface_vertex as usize];
        let new = rest + e.displacement;
        if inst.nodes[e.node as usize].kind == NodeKind::FaceA {
            assert!((new.x - 0.031).abs() < 1e-12, "{e:?} {rest}");
        } else {
            assert!((new.x - 0.029).abs() < 1e-12, "{e:?} {rest}");
        }
        assert_eq!(e.volume_node, surf.to_volume[e.surface_vertex as usize]);
    }
    let deepest = out.enforced.iter().map(|e| e.depth).fold(0.0, f64::max);
    assert!((deepest - 1.0 * MM).abs() < 1e-12, "{deepest}");
    assert_eq!(hist.active(), a + b, "flags follow the surviving pairs");
}

/// (b) A spatula swinging in the U valley about a pivot on the valley's
/// centre line at mid-depth (20 mm), tip 8 mm below the pivot. Tilting the tip
/// to +x brings the upper part of face B into the upper left wall; tilting it
/// to -x brings the upper part of face A into the upper right wall. Each face
/// only ever pairs with the wall it looks at, the lower part of the plate
/// (whose faces meet the shallow lower walls at an angle that A2 rejects) has
/// no pair, and deep pairs of the far face are culled.
#[test]
fn u_valley_swing_gives_each_face_its_own_wall() {
    let mesh = blocks::u_valley();
    let surf = Surface::new(&mesh);
    let mut bvh = surf.backend();
    let inst = Instrument::new(
        Plate::flat(2.0 * MM, 10.0 * MM, 40.0 * MM),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .unwrap();
    let mut hist = History::new(&inst, HistoryMode::ForceRate);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let pivot = Point3::new(0.03, 0.015, 0.02);
    let (mut most_a, mut most_b, mut culled) = (0, 0, 0);
    // From upright to +65 degrees, back through upright to -65 degrees.
    for k in (0i32..=65).chain((-65i32..65).rev()) {
        // Rotation about +y by -theta tilts the tip towards +x.
        let theta = -(k as f64).to_radians();
        let rot = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), theta)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI);
        let handle = pivot + rot * Vector3::new(0.0, 0.0, -0.032);
        let pose = Isometry3::from_parts(Translation3::from(handle.coords), rot);
        detect(
            &mut bvh,
            &surf.query(),
            &inst,
            &pose,
            &mut hist,
            Stage::Force,
            &DetectOptions::paper(),
            &mut ws,
            &mut out,
        )
        .unwrap();
        let (mut a, mut b) = (0, 0);
        for p in &out.pairs {
            let v = surf.verts(p);
            match kind(&inst, p) {
                NodeKind::FaceA => {
                    assert!(
                        k < 0 && v.iter().all(|q| q.x > 0.03 && q.z > pivot.z),
                        "k {k}: A pair {p:?} {v:?}"
                    );
                    a += 1;
                }
                NodeKind::FaceB => {
                    assert!(
                        k > 0 && v.iter().all(|q| q.x < 0.03 && q.z > pivot.z),
                        "k {k}: B pair {p:?} {v:?}"
                    );
                    b += 1;
                }
                k => panic!("no rim nodes here: {k:?}"),
            }
        }
        most_a = most_a.max(a);
        most_b = most_b.max(b);
        culled += out.cancelled.len();
    }
    assert!(most_a >= 30 && most_b >= 30, "A {most_a} B {most_b}");
    assert!(
        culled > 0,
        "the deepest poses (static surface) need culling"
    );
}

/// A wall (the face x = 0 of a 30 mm cube) and a vertical plate parallel to it.
fn wall_setup() -> (Surface, Instrument) {
    let mesh = blocks::cube(0.03, 8);
    let inst = Instrument::new(
        Plate::flat(1.0 * MM, 10.0 * MM, 20.0 * MM),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .unwrap();
    (Surface::new(&mesh), inst)
}

/// Plate centred at x = `x`, tip down at z = 5 mm, centred in y.
fn wall_pose(x: f64) -> Isometry3<f64> {
    down(Point3::new(x, 0.015, 0.025))
}

fn far_face_pairs(surf: &Surface, inst: &Instrument, out: &ContactOutput) -> usize {
    out.pairs
        .iter()
        .filter(|p| {
            kind(inst, p) == NodeKind::FaceB
                && surf.verts(p).iter().all(|q| (q.x - 0.03).abs() < 1e-12)
        })
        .count()
}

/// (c) Deep penetration (the paper's Figure 6): after a shallow contact, the
/// plate is 3.5 thicknesses into the wall. Face B then finds the cube's far
/// face behind it with an opposing normal: without culling these pairs survive
/// (they would pull the far face through the instrument); with culling every
/// one of them is cancelled, while face A keeps pushing the wall.
#[test]
fn deep_penetration_far_face_pairs_only_without_culling() {
    let (surf, inst) = wall_setup();
    for culling in [false, true] {
        let mut bvh = surf.backend();
        let mut hist = History::new(&inst, HistoryMode::ForceRate);
        let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
        let opts = DetectOptions {
            culling,
            ..DetectOptions::paper()
        };
        for x in [-0.2 * MM, 3.0 * MM] {
            detect(
                &mut bvh,
                &surf.query(),
                &inst,
                &wall_pose(x),
                &mut hist,
                Stage::Deformation,
                &opts,
                &mut ws,
                &mut out,
            )
            .unwrap();
        }
        let wall = out
            .pairs
            .iter()
            .filter(|p| {
                kind(&inst, p) == NodeKind::FaceA && surf.verts(p).iter().all(|q| q.x == 0.0)
            })
            .count();
        let far = far_face_pairs(&surf, &inst, &out);
        assert_eq!(wall, 150, "face A pushes the wall (culling {culling})");
        if culling {
            assert_eq!(far, 0);
            assert_eq!(out.cancelled.len(), 150, "every far-face pair is cancelled");
            assert!(out.pairs.iter().all(|p| kind(&inst, p) == NodeKind::FaceA));
        } else {
            assert_eq!(far, 150, "the paper's failure without culling");
            assert!(out.cancelled.is_empty());
        }
    }
}

/// (d) Fast travel, 5 thicknesses per deformation step, 50 force-loop samples
/// per deformation step. In the paper-faithful mode the history is renewed
/// only at deformation steps: the step that jumps from before the wall to deep
/// inside it has no flags, and the far-face pairs survive. With the history
/// renewed at the force-loop rate, first contact is seen by a force sample and
/// the deformation step's far-face pairs are all cancelled.
#[test]
fn fast_travel_defeats_paper_history_not_force_rate_history() {
    let (surf, inst) = wall_setup();
    let h = inst.plate.thickness;
    let samples = 50;
    let mut far = Vec::new();
    for mode in [HistoryMode::PaperFaithful, HistoryMode::ForceRate] {
        let mut bvh = surf.backend();
        let mut hist = History::new(&inst, mode);
        let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
        let opts = DetectOptions::paper();
        // Face A starts 0.3 mm before the wall.
        let x0 = -0.5 * h - 0.3 * MM;
        let mut worst = 0;
        for step in 0..=1 {
            for s in 1..=samples {
                let x = x0 + 5.0 * h * (step as f64 - 1.0 + s as f64 / samples as f64);
                if step == 0 {
                    continue;
                }
                detect(
                    &mut bvh,
                    &surf.query(),
                    &inst,
                    &wall_pose(x),
                    &mut hist,
                    Stage::Force,
                    &opts,
                    &mut ws,
                    &mut out,
                )
                .unwrap();
            }
            let x = x0 + 5.0 * h * step as f64;
            detect(
                &mut bvh,
                &surf.query(),
                &inst,
                &wall_pose(x),
                &mut hist,
                Stage::Deformation,
                &opts,
                &mut ws,
                &mut out,
            )
            .unwrap();
            worst = worst.max(far_face_pairs(&surf, &inst, &out));
            if step == 0 {
                assert!(out.pairs.is_empty(), "no contact before the wall");
            } else {
                assert_eq!(
                    out.pairs
                        .iter()
                        .filter(|p| kind(&inst, p) == NodeKind::FaceA)
                        .count(),
                    150
                );
            }
        }
        far.push(worst);
    }
    assert_eq!(
        far,
        vec![150, 0],
        "far-face pairs at deformation steps: [paper, force-rate]"
    );
}

/// Paper-faithful force-loop calls read the flags but do not renew them.
#[test]
fn paper_mode_force_calls_do_not_renew() {
    let (surf, inst) = wall_setup();
    let mut bvh = surf.backend();
    let mut hist = History::new(&inst, HistoryMode::PaperFaithful);
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let opts = DetectOptions::paper();
    let q = surf.query();
    detect(
        &mut bvh,
        &q,
        &inst,
        &wall_pose(-0.3 * MM),
        &mut hist,
        Stage::Force,
        &opts,
        &mut ws,
        &mut out,
    )
    .unwrap();
    assert_eq!(out.pairs.len(), 150);
    assert_eq!(hist.active(), 0);
    detect(
        &mut bvh,
        &q,
        &inst,
        &wall_pose(-0.3 * MM),
        &mut hist,
        Stage::Deformation,
        &opts,
        &mut ws,
        &mut out,
    )
    .unwrap();
    assert_eq!(hist.active(), 150);
    let mut copy = History::new(&inst, HistoryMode::ForceRate);
    copy.copy_from(&hist);
    assert_eq!(copy, hist);
}

/// A block 60 x 30 x 30 mm with a slot 2 mm wide (29 < x < 31 mm) and 20 mm
/// deep (z > 10 mm) along y: a fissure with parallel walls.
fn slot_block() -> TetMesh {
    let n = [15, 6, 6];
    let base = blocks::cuboid([1.0, 1.0, 1.0], n);
    let map_x = |i: usize| {
        if i <= 7 {
            i as f64 * 29.0 / 7.0
        } else {
            31.0 + (i - 8) as f64 * 29.0 / 7.0
        }
    };
    let nodes: Vec<Point3<f64>> = base
        .nodes
        .iter()
        .map(|p| {
            let i = (p.x * n[0] as f64).round() as usize;
            Point3::new(map_x(i) * MM, p.y * 0.03, p.z * 0.03)
        })
        .collect();
    let tets = base
        .tets
        .iter()
        .copied()
        .filter(|t| {
            let c = t
                .iter()
                .fold(Vector3::zeros(), |s, &v| s + nodes[v as usize].coords)
                / 4.0;
            !(c.x > 29.0 * MM && c.x < 31.0 * MM && c.z > 10.0 * MM)
        })
        .collect();
    TetMesh::new(nodes, tets).unwrap()
}

/// (e) Two spatulas in the slot pushed apart, in one deformation-loop call:
/// the left one's face B opens the left wall, the right one's face A the right
/// wall; the walls end on the outer faces' planes.
#[test]
fn fissure_slot_two_spatulas_open_the_slot() {
    let surf = Surface::new(&slot_block());
    let mut bvh = surf.backend();
    let inst = Instrument::new(
        Plate::flat(0.8 * MM, 10.0 * MM, 30.0 * MM),
        NodeLayout::WholeFace { per_face: 150 },
        None,
    )
    .unwrap();
    let mut h = [
        History::new(&inst, HistoryMode::ForceRate),
        History::new(&inst, HistoryMode::ForceRate),
    ];
    let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
    let steps = 30;
    let spread = 1.5 * MM;
    for k in 0..=steps {
        let d = spread * k as f64 / steps as f64;
        let [h0, h1] = &mut h;
        let mut tools = [
            Tool {
                instrument: &inst,
                pose: down(Point3::new(0.0296 - d, 0.015, 0.044)),
                history: h0,
            },
            Tool {
                instrument: &inst,
                pose: down(Point3::new(0.0304 + d, 0.015, 0.044)),
                history: h1,
            },
        ];
        detect_many(
            &mut bvh,
            &surf.query(),
            &mut tools,
            Stage::Deformation,
            &DetectOptions::paper(),
            &mut ws,
            &mut out,
        )
        .unwrap();
        for p in &out.pairs {
            let v = surf.verts(p);
            match (p.instrument, kind(&inst, p)) {
                (0, NodeKind::FaceB) => {
                    assert!(v.iter().all(|q| (q.x - 0.029).abs() < 1e-12), "{v:?}")
                }
                (1, NodeKind::FaceA) => {
                    assert!(v.iter().all(|q| (q.x - 0.031).abs() < 1e-12), "{v:?}")
                }
                other => panic!("unexpected pair {other:?} {p:?}"),
            }
        }
    }
    assert!(out.pairs_of(0).count() > 50 && out.pairs_of(1).count() > 50);
    // Spread 1.5 mm > thickness 0.8 mm against a static surface: each spatula
    // ends fully inside its wall, so its inner face finds the block's outer
    // face behind it; all those pairs are culled.
    assert!(!out.cancelled.is_empty());
    for p in &out.cancelled {
        let v = surf.verts(p);
        let (inner, outer) = match p.instrument {
            0 => (NodeKind::FaceA, 0.0),
            _ => (NodeKind::FaceB, 0.06),
        };
        assert_eq!(kind(&inst, p), inner);
        assert!(v.iter().all(|q| (q.x - outer).abs() < 1e-12), "{v:?}");
    }
    let (b_plane, a_plane) = (0.0296 - spread - 0.4 * MM, 0.0304 + spread + 0.4 * MM);
    for e in &out.enforced {
        let x = surf.pos[e.surface_vertex as usize].x + e.displacement.x;
        let plane = if e.instrument == 0 { b_plane } else { a_plane };
        assert!((x - plane).abs() < 1e-12, "{e:?}");
    }
}
