//! Stage 3 of the pipeline ([`super`], the contact module): history culling (B1-B3),
//! per instrument.
//!
//! Every node whose history flag is on marks its nearest triangle *in
//! front* as infeasible; every pair of that instrument holding an
//! infeasible triangle is cancelled ([`ContactOutput::cancelled`]). Culling
//! is per instrument because a triangle in front of one spatula may be a
//! genuine contact of the other (two spatulas squeezing a lobe from both
//! sides).
//!
//! With the Signorini rule a flagged node marks its front triangle only
//! when that triangle does not face it (`N_R . N_tri >= 0`): a triangle
//! that does is tissue on the node's own side (the face retracting from
//! it, or about to touch it), while the triangles that would pull tissue
//! through the plate, the far side of what the face pushes, face the way
//! the node does. The paper's rule marks every front triangle.

use super::types::{ContactOutput, ContactQuery, ContactRule, DetectOptions};
use super::workspace::{Tool, Workspace};

/// Splits `ws.candidates` into `out.pairs` and `out.cancelled`.
pub(crate) fn cull(
    query: &ContactQuery<'_>,
    tools: &mut [Tool<'_>],
    opts: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) {
    let mut c = 0;
    for (k, tool) in tools.iter_mut().enumerate() {
        let first = ws.offsets[k];
        tool.history.ensure_len(tool.instrument.len());
        if opts.culling {
            ws.next_stamp(query.triangles.len());
            for (i, &flag) in tool.history.flags().iter().enumerate() {
                if !flag {
                    continue;
                }
                let Some(front) = ws.hits.get(first + i).and_then(|h| h.front) else {
                    continue;
                };
                if opts.rule == ContactRule::Signorini {
                    let Some(tri) = query.triangles.get(front.triangle as usize) else {
                        continue;
                    };
                    let [a, b, cc] = tri.map(|v| query.positions[v as usize]);
                    if ws.dirs[first + i].dot(&(b - a).cross(&(cc - a))) < 0.0 {
                        continue;
                    }
                }
                if let Some(m) = ws.mark.get_mut(front.triangle as usize) {
                    *m = ws.stamp;
                }
            }
        }
        while c < ws.candidates.len() && ws.candidates[c].instrument as usize == k {
            let p = ws.candidates[c];
            c += 1;
            if opts.culling && ws.mark[p.triangle as usize] == ws.stamp {
                out.cancelled.push(p);
            } else {
                out.pairs.push(p);
            }
        }
    }
}
