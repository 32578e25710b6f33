//! Stage 2 of the pipeline ([`super`], the contact module): collision pairs (A1, A2).
//!
//! The nearest triangle behind a node (`t <= 0`, within the node's reach)
//! forms a pair with it when the triangle's outward normal opposes the face
//! normal, `N_R . N_tri < 0` (`N_tri` at the current positions). With the
//! Signorini rule a node without such a pair also pairs with its nearest
//! triangle in front within the band (`0 < t <= band_m`) by the same normal
//! test: tissue the face is about to touch, or is leaving while the tissue
//! still pushes on it.

use super::types::{ContactError, ContactQuery, DetectOptions, Pair};
use super::workspace::{Tool, Workspace};
use crate::collide::rays::SurfaceError;

/// The pairs of every tool, in (instrument, node) order, into
/// `ws.candidates`.
pub(crate) fn pair(
    query: &ContactQuery<'_>,
    tools: &[Tool<'_>],
    opts: &DetectOptions,
    ws: &mut Workspace,
) -> Result<(), ContactError> {
    ws.candidates.clear();
    let nv = query.positions.len();
    let band = opts.front_band();
    for (k, tool) in tools.iter().enumerate() {
        let first = ws.offsets[k];
        for (i, node) in tool.instrument.nodes.iter().enumerate() {
            let g = first + i;
            let Some(hits) = ws.hits.get(g) else {
                continue;
            };
            let behind = hits.behind.filter(|h| -h.t <= node.reach);
            let front = hits.front.filter(|h| band > 0.0 && h.t <= band);
            for hit in [behind, front].into_iter().flatten() {
                let triangle = hit.triangle as usize;
                let tri =
                    query
                        .triangles
                        .get(triangle)
                        .ok_or(SurfaceError::TriangleOutOfRange {
                            triangle,
                            triangles: query.triangles.len(),
                        })?;
                if let Some(&vertex) = tri.iter().find(|&&v| v as usize >= nv) {
                    return Err(SurfaceError::VertexOutOfRange {
                        triangle,
                        vertex,
                        vertices: nv,
                    }
                    .into());
                }
                let [a, b, c] = tri.map(|v| query.positions[v as usize]);
                let n_tri = (b - a).cross(&(c - a));
                if ws.dirs[g].dot(&n_tri) < 0.0 {
                    ws.candidates.push(Pair {
                        instrument: k as u16,
                        node: i as u32,
                        triangle: hit.triangle,
                        t: hit.t,
                        u: hit.u,
                        v: hit.v,
                    });
                    break;
                }
            }
        }
    }
    Ok(())
}
