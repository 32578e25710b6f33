//! Stage 5 of the pipeline ([`super`], the contact module) with the paper's rule:
//! enforced displacements.
//!
//! For each surviving pair and each vertex `V` of its triangle, with current
//! position `V` and rest position `V_rest`: `depth = (S - V) . N_R`,
//! `V_proj = V + depth N_R` (the projection onto the face plane along
//! `N_R`), `U = V_proj - V_rest`. **Conflict rule:** when several pairs give
//! one vertex different displacements, the one with the largest `depth`
//! wins (the face the vertex has penetrated deepest, so that the vertex
//! ends up outside every face that claims it as far as one projection
//! can); equal depths keep the first in (instrument, node) order. Each
//! [`Enforced`] records the instrument and node that gave it, so reactions
//! can be summed per instrument.
//!
//! Every vertex of a paired triangle is projected, even one in front of the
//! face or beyond its outline: the rule pulls such tissue onto the plate
//! and fixes all three components (no sliding), which is why the Signorini
//! rule ([`super::gap`]) is the default; this one is kept for comparison
//! with the paper.

use super::types::{ContactOutput, ContactQuery, DetectOptions, Enforced, NONE};
use super::workspace::Workspace;

/// `out.enforced` from `out.pairs`.
pub(crate) fn project(
    query: &ContactQuery<'_>,
    _opts: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) {
    let nv = query.positions.len();
    if ws.slot.len() != nv {
        ws.slot.clear();
        ws.slot.resize(nv, NONE);
    }
    for p in &out.pairs {
        let g = ws.offsets[p.instrument as usize] + p.node as usize;
        let (s, n) = (ws.origins[g], ws.dirs[g]);
        for v in query.triangles[p.triangle as usize] {
            let pos = query.positions[v as usize];
            let depth = (s - pos).dot(&n);
            let e = Enforced {
                surface_vertex: v,
                volume_node: query.to_volume[v as usize],
                displacement: pos + n * depth - query.rest[v as usize],
                instrument: p.instrument,
                node: p.node,
                depth,
            };
            let slot = &mut ws.slot[v as usize];
            if *slot == NONE {
                *slot = out.enforced.len() as u32;
                out.enforced.push(e);
            } else if depth > out.enforced[*slot as usize].depth {
                out.enforced[*slot as usize] = e;
            }
        }
    }
    for e in &out.enforced {
        ws.slot[e.surface_vertex as usize] = NONE;
    }
}
