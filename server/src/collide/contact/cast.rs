//! Stage 1 of the pipeline ([`super`], the contact module): the source-node rays and
//! the cast.
//!
//! Each source node `S` with unit face normal `N_R` (scene frame, after the
//! pose) gives the line `S + t N_R`. All nodes of all instruments are cast
//! in one [`RayBackend::cast_ranged`]; rays start from `S + skin N_R`
//! ([`DetectOptions::skin_m`]) and their answers are reported from the true
//! face point. With bounded rays each line looks behind up to the node's
//! reach, in front up to the band (Signorini rule), and, from nodes whose
//! history flag is on, in front up to the reach (the culling reads it).
//! [`recast_for_culling`] casts flagged lines again beyond their reach when
//! the culling could still need their nearest front hit.

use super::types::{DetectOptions, widen};
use super::workspace::{Tool, Workspace};
use crate::collide::rays::{RayBackend, RayRange};
use nalgebra::{Point3, Vector3};

/// The rays of all tools, and their first cast.
pub(crate) fn cast(
    backend: &mut dyn RayBackend,
    tools: &[Tool<'_>],
    opts: &DetectOptions,
    ws: &mut Workspace,
) {
    ws.origins.clear();
    ws.dirs.clear();
    ws.offsets.clear();
    for tool in tools {
        ws.offsets.push(ws.origins.len());
        tool.instrument
            .place(&tool.pose, &mut ws.origins, &mut ws.dirs);
    }
    ws.offsets.push(ws.origins.len());
    let skin = opts.skin();
    if skin > 0.0 {
        for (o, d) in ws.origins.iter_mut().zip(&ws.dirs) {
            *o += d * skin;
        }
    }
    let look = opts.front_look();
    ws.ranges.clear();
    for tool in tools {
        let flags = tool.history.flags();
        ws.ranges
            .extend(tool.instrument.nodes.iter().enumerate().map(|(i, node)| {
                if opts.bounded_rays {
                    // Pairs need the nearest hit behind only within reach
                    // (from the true face point, hence the skin), and in
                    // front within the band (the gap stage looks a little
                    // farther); the culling needs the nearest hit in front
                    // of flagged nodes.
                    let flagged = opts.culling && flags.get(i).copied().unwrap_or(false);
                    let mut front = if flagged {
                        front_reach(node.reach)
                    } else {
                        -1.0
                    };
                    if look > 0.0 {
                        front = front.max(widen(look));
                    }
                    RayRange {
                        behind: widen(node.reach + skin),
                        front,
                    }
                } else {
                    RayRange::LINE
                }
            }));
    }
    backend.cast_ranged(&ws.origins, &ws.dirs, &ws.ranges, &mut ws.hits);
    if skin > 0.0 {
        // Back to the true face points. The shifted origins classified the hits
        // (behind: t_true <= skin); report t from the true face point.
        for (o, d) in ws.origins.iter_mut().zip(&ws.dirs) {
            *o -= d * skin;
        }
        for h in ws.hits.iter_mut() {
            for hit in [&mut h.behind, &mut h.front].into_iter().flatten() {
                hit.t += skin;
            }
        }
    }
}

/// Flagged lines with nothing in front within reach: their nearest front
/// hit matters only if it is a pair triangle of their instrument, so they
/// are cast again, beyond reach, only when they meet the box of those
/// triangles (which holds any such hit). Needs the pairs of
/// [`super::pair::pair`] (in `ws.candidates`).
pub(crate) fn recast_for_culling(
    backend: &mut dyn RayBackend,
    query: &super::types::ContactQuery<'_>,
    tools: &[Tool<'_>],
    opts: &DetectOptions,
    ws: &mut Workspace,
) {
    if !(opts.culling && opts.bounded_rays) {
        return;
    }
    let skin = opts.skin();
    ws.recast.clear();
    ws.recast_origins.clear();
    ws.recast_dirs.clear();
    ws.recast_ranges.clear();
    let mut c = 0;
    for (k, tool) in tools.iter().enumerate() {
        let first = ws.offsets[k];
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        while c < ws.candidates.len() && ws.candidates[c].instrument as usize == k {
            for v in query.triangles[ws.candidates[c].triangle as usize] {
                let p = query.positions[v as usize];
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
            c += 1;
        }
        if lo.x > hi.x {
            continue;
        }
        let (lo, hi) = crate::collide::rays::widen_box(lo, hi);
        for (i, &flag) in tool.history.flags().iter().enumerate() {
            let g = first + i;
            if !flag || ws.hits[g].front.is_some() {
                continue;
            }
            let beyond = ws.ranges[g].front;
            if !beyond.is_finite() {
                continue;
            }
            let o = ws.origins[g] + ws.dirs[g] * skin;
            if line_meets_box(&o, &ws.dirs[g], beyond, &lo, &hi) {
                ws.recast.push(g);
                ws.recast_origins.push(o);
                ws.recast_dirs.push(ws.dirs[g]);
                ws.recast_ranges.push(RayRange {
                    behind: -1.0,
                    front: f64::INFINITY,
                });
            }
        }
    }
    if !ws.recast.is_empty() {
        backend.cast_ranged(
            &ws.recast_origins,
            &ws.recast_dirs,
            &ws.recast_ranges,
            &mut ws.recast_hits,
        );
        for (j, &g) in ws.recast.iter().enumerate() {
            ws.hits[g].front = ws.recast_hits[j].front.map(|mut h| {
                h.t += skin;
                h
            });
        }
    }
}

/// How far in front a flagged node's line is cast in the first pass, m: its
/// reach (hits there are found with the behind ones, from the same region
/// of the tree).
#[inline]
fn front_reach(reach: f64) -> f64 {
    if reach.is_finite() {
        widen(reach)
    } else {
        f64::INFINITY
    }
}

/// Whether the part `t > beyond` of the line `o + t d` meets the box
/// `[lo, hi]` (slab test; a zero direction component needs `o` within that
/// slab).
fn line_meets_box(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    beyond: f64,
    lo: &Point3<f64>,
    hi: &Point3<f64>,
) -> bool {
    let (mut t0, mut t1) = (beyond, f64::INFINITY);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return false;
            }
        } else {
            let inv = 1.0 / d[a];
            let (ta, tb) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    // Widened: a hit exactly on the box boundary must not be missed.
    t0 <= t1 + 1e-9 * (t1.abs() + 1.0)
}
