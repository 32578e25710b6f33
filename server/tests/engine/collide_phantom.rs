//! The paper's situations in a fissure of the brain phantom (the coarse
//! preset's left Sylvian fissure, placed from the landmarks): a spatula inserted
//! into the fissure and pushed into one wall pairs only with that wall, and no
//! infeasible pair survives; pushed deep into the wall, its far face finds the
//! lobe's outer surface behind it, which only culling removes.
//!
//! As in `collide_paper.rs`, the surface stays at rest (the force loop's view
//! between two deformation steps).

use fissure_engine::collide::{
    Bvh, ContactOutput, ContactQuery, DetectOptions, FissurePlacement, History, HistoryMode,
    Instrument, NodeKind, NodeLayout, Plate, Stage, Workspace, detect,
};
use fissure_engine::mesh::phantom::{self, FissureLandmark};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::HashSet;

const MM: f64 = 1e-3;

struct Fissure {
    pos: Vec<Point3<f64>>,
    tris: Vec<[u32; 3]>,
    to_volume: Vec<u32>,
    f: FissureLandmark,
    inst: Instrument,
}

impl Fissure {
    fn coarse() -> Self {
        let p = phantom::preset("coarse").unwrap();
        let s = p.mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&p.mesh.nodes, &mut pos);
        let inst = Instrument::new(
            Plate::flat(1.0 * MM, 8.0 * MM, 30.0 * MM),
            NodeLayout::WholeFace { per_face: 150 },
            None,
        )
        .unwrap();
        Self {
            pos,
            tris: s.triangles,
            to_volume: s.to_volume,
            f: p.landmarks.sylvian_left,
            inst,
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

    /// Tip 15 mm past the entry, centred on the entry, mid-plane at `offset`
    /// along the fissure's normal.
    fn pose(&self, offset: f64) -> Isometry3<f64> {
        FissurePlacement {
            insertion: 15.0 * MM,
            across: 0.0,
            offset,
        }
        .pose(&self.f, self.inst.plate.length)
    }

    /// Signed distance of triangle `t`'s centroid from the fissure's mid-plane.
    fn side(&self, t: u32) -> f64 {
        let [a, b, c] = self.tris[t as usize].map(|v| self.pos[v as usize]);
        let g = Point3::from((a.coords + b.coords + c.coords) / 3.0);
        (g - self.f.entry).dot(&self.f.normal)
    }

    fn outward(&self, t: u32) -> Vector3<f64> {
        let [a, b, c] = self.tris[t as usize].map(|v| self.pos[v as usize]);
        (b - a).cross(&(c - a)).normalize()
    }

    /// Runs `offsets` in order with one history; the last step's output and the
    /// triangles that step found infeasible (nearest in front of a node flagged
    /// by the step before).
    fn push(&self, offsets: &[f64], culling: bool) -> (ContactOutput, HashSet<u32>) {
        let mut bvh = Bvh::new(&self.tris, &self.pos).unwrap();
        let mut hist = History::new(&self.inst, HistoryMode::ForceRate);
        let (mut ws, mut out) = (Workspace::new(), ContactOutput::default());
        let opts = DetectOptions {
            culling,
            ..DetectOptions::paper()
        };
        let mut infeasible = HashSet::new();
        for &o in offsets {
            let flags = hist.flags().to_vec();
            detect(
                &mut bvh,
                &self.query(),
                &self.inst,
                &self.pose(o),
                &mut hist,
                Stage::Deformation,
                &opts,
                &mut ws,
                &mut out,
            )
            .unwrap();
            infeasible = flags
                .iter()
                .zip(&ws.hits)
                .filter(|(f, _)| **f)
                .filter_map(|(_, h)| h.front.map(|h| h.triangle))
                .collect();
        }
        (out, infeasible)
    }
}

/// Inserted into the fissure and pushed 0.5 mm into the wall at `+width/2`:
/// only face A pairs, every pair holds a triangle of that wall (on the `+n`
/// side of the mid-plane, facing the gap), and no pair holds an infeasible
/// triangle.
#[test]
fn push_into_one_wall_pairs_only_with_that_wall() {
    let fis = Fissure::coarse();
    let f = fis.f;
    let h = fis.inst.plate.thickness;
    let target = FissurePlacement::into_wall(&f, h, 0.5 * MM);
    // Slide in along the mid-plane, then move across onto the wall in steps
    // well under the thickness (the force loop's rate).
    let offsets: Vec<f64> = (0..=8).map(|k| target * k as f64 / 8.0).collect();
    let (out, infeasible) = fis.push(&offsets, true);
    assert!(
        out.pairs.len() >= 20,
        "face A touches the wall: {} pairs",
        out.pairs.len()
    );
    for p in &out.pairs {
        assert_eq!(
            fis.inst.nodes[p.node as usize].kind,
            NodeKind::FaceA,
            "{p:?}"
        );
        assert!(
            fis.side(p.triangle) > 0.0,
            "pair {p:?} holds a triangle on the far side of the fissure"
        );
        assert!(
            fis.outward(p.triangle).dot(&f.normal) < 0.0,
            "pair {p:?}: the wall faces the gap"
        );
        assert!(
            !infeasible.contains(&p.triangle),
            "infeasible pair survived: {p:?}"
        );
        // Behind face A by at most the push (plus the wall's facet tilt).
        assert!(p.t <= 0.0 && p.t > -3.0 * MM, "{p:?}");
    }
    // The other wall is untouched.
    assert!(
        out.enforced
            .iter()
            .all(|e| { (fis.pos[e.surface_vertex as usize] - f.entry).dot(&f.normal) > 0.0 })
    );
}

/// Deep push (the paper's Figure 6 in the fissure): from a shallow contact the
/// plate moves on, 0.25 mm per force-loop step, until all of it is 1 mm inside
/// the upper wall. Face B then finds the lobe's
/// outer surface behind it, facing away from it: without culling these pairs
/// survive; with culling they are all cancelled, and face A keeps pushing the
/// wall.
#[test]
fn deep_push_far_face_pairs_only_without_culling() {
    let fis = Fissure::coarse();
    let f = fis.f;
    let h = fis.inst.plate.thickness;
    let shallow = FissurePlacement::into_wall(&f, h, 0.5 * MM);
    let deep = 0.5 * f.width + 1.0 * MM + 0.5 * h;
    let mut far_counts = Vec::new();
    for culling in [false, true] {
        let steps = ((deep - shallow) / (0.25 * MM)).ceil() as usize;
        let offsets: Vec<f64> = (0..=steps)
            .map(|k| shallow + (deep - shallow) * k as f64 / steps as f64)
            .collect();
        let (out, infeasible) = fis.push(&offsets, culling);
        let far: Vec<_> = out
            .pairs
            .iter()
            .filter(|p| fis.inst.nodes[p.node as usize].kind == NodeKind::FaceB)
            .collect();
        let wall = out
            .pairs
            .iter()
            .filter(|p| {
                fis.inst.nodes[p.node as usize].kind == NodeKind::FaceA
                    && fis.outward(p.triangle).dot(&f.normal) < 0.0
            })
            .count();
        assert!(
            wall >= 20,
            "face A pushes the wall (culling {culling}): {wall}"
        );
        for p in &far {
            // Far-face pairs hold the lobe's outer surface beyond the wall.
            assert!(fis.side(p.triangle) > deep, "{p:?}");
        }
        if culling {
            assert!(
                far.is_empty(),
                "{} far-face pairs survived culling",
                far.len()
            );
            assert!(
                out.cancelled.len() >= far_counts[0],
                "every far-face pair is cancelled"
            );
            assert!(out.pairs.iter().all(|p| !infeasible.contains(&p.triangle)));
            assert!(
                out.cancelled
                    .iter()
                    .all(|p| infeasible.contains(&p.triangle))
            );
        } else {
            assert!(
                far.len() >= 20,
                "the paper's failure without culling: {} far-face pairs",
                far.len()
            );
            assert!(out.cancelled.is_empty());
        }
        far_counts.push(far.len());
    }
}
