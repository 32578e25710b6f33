//! The stuffing cut: every background tetrahedron the isosurface crosses is
//! replaced by the stencil of its vertex signs (cut points on its edges at
//! the roots of the field, vertices near the surface warped onto it), and
//! the tetrahedra inside are kept.

use super::{
    ALPHA_LONG, ALPHA_SHORT, Background, PROVEN_MAX_DIHEDRAL_DEG, PROVEN_MIN_DIHEDRAL_DEG,
    StuffingError, TET_EDGES, edge_key, key_ends, lattice_len2, parity, tet_dihedrals,
};
use crate::mesh::TetMesh;
use crate::mesh::sdf::{Sdf, edge_root};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

impl Background {
    pub(super) fn stuff(self, sdf: &dyn Sdf) -> Result<TetMesh, StuffingError> {
        let Background {
            origin,
            unit,
            spacing,
            coords,
            values,
            tets,
            bcc,
            parity,
        } = self;
        let ref_pos: Vec<Point3<f64>> = coords
            .iter()
            .map(|c| origin + Vector3::new(c[0] as f64, c[1] as f64, c[2] as f64) * unit)
            .collect();
        let nv = coords.len();
        let len2 = |a: u32, b: u32| lattice_len2(&coords, a, b);
        // Edges, and which are the longest edge of some tetrahedron.
        let mut edges: Vec<(u64, bool)> = tets
            .par_iter()
            .flat_map_iter(|t| {
                let l: [i64; 6] = TET_EDGES.map(|(i, j)| len2(t[i], t[j]));
                let max = *l.iter().max().unwrap_or(&0);
                TET_EDGES
                    .iter()
                    .zip(l)
                    .map(move |(&(i, j), li)| (edge_key(t[i], t[j]), li == max))
                    .collect::<Vec<_>>()
            })
            .collect();
        edges.par_sort_unstable();
        // Merge duplicates: an edge is "long" when it is longest in any tetrahedron.
        let mut merged: Vec<(u64, bool)> = Vec::with_capacity(edges.len() / 4);
        for (k, long) in edges {
            match merged.last_mut() {
                Some((lk, ll)) if *lk == k => *ll |= long,
                _ => merged.push((k, long)),
            }
        }
        let edges = merged;
        let sign = |f: f64| -> i8 {
            if f < 0.0 {
                -1
            } else if f > 0.0 {
                1
            } else {
                0
            }
        };
        let tol = 1e-6 * spacing;
        let field = |p: &Point3<f64>| sdf.distance(p);
        // Cut points on edges with strictly opposite signs.
        let cuts: Vec<Option<Point3<f64>>> = edges
            .par_iter()
            .map(|&(k, _)| {
                let (a, b) = key_ends(k);
                let (fa, fb) = (values[a as usize], values[b as usize]);
                if sign(fa) * sign(fb) >= 0 {
                    return None;
                }
                let (pa, pb) = (ref_pos[a as usize], ref_pos[b as usize]);
                let t = edge_root(&field, &pa, &pb, fa, fb, tol);
                Some(pa + (pb - pa) * t)
            })
            .collect();
        // Vertex -> incident edges (CSR).
        let mut start = vec![0u32; nv + 1];
        for &(k, _) in &edges {
            let (a, b) = key_ends(k);
            start[a as usize + 1] += 1;
            start[b as usize + 1] += 1;
        }
        for i in 0..nv {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut incident = vec![0u32; start[nv] as usize];
        for (ei, &(k, _)) in edges.iter().enumerate() {
            let (a, b) = key_ends(k);
            for v in [a, b] {
                incident[fill[v as usize] as usize] = ei as u32;
                fill[v as usize] += 1;
            }
        }
        // Warping and stencils. A vertex whose warp would invert an output
        // tetrahedron is left in place (its nearby cut point stays) and the
        // pass is repeated.
        let cuts0 = cuts;
        let mut no_warp = vec![false; nv];
        let mut attempts = 0;
        loop {
            let mut cuts = cuts0.clone();
            let mut warped = vec![false; nv];
            let mut pos = ref_pos.clone();
            let mut val = values.clone();
            for v in 0..nv {
                if no_warp[v] {
                    continue;
                }
                let inc = &incident[start[v] as usize..start[v + 1] as usize];
                let mut best: Option<(f64, Point3<f64>)> = None;
                for &ei in inc {
                    let (k, long) = edges[ei as usize];
                    let Some(c) = cuts[ei as usize] else { continue };
                    let (a, b) = key_ends(k);
                    let len = (ref_pos[b as usize] - ref_pos[a as usize]).norm();
                    let d = (c - ref_pos[v]).norm();
                    let alpha = if long { ALPHA_LONG } else { ALPHA_SHORT };
                    if d < alpha * len && best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, c));
                    }
                }
                if let Some((_, c)) = best {
                    warped[v] = true;
                    pos[v] = c;
                    val[v] = 0.0;
                    for &ei in inc {
                        cuts[ei as usize] = None;
                    }
                }
            }
            // Cut point node ids: nv + rank among surviving cuts.
            let mut cut_id = vec![u32::MAX; edges.len()];
            let mut cut_pos = Vec::new();
            for (ei, c) in cuts.iter().enumerate() {
                if let Some(c) = c {
                    cut_id[ei] = (nv + cut_pos.len()) as u32;
                    cut_pos.push(*c);
                }
            }
            let edge_index = |a: u32, b: u32| -> Option<usize> {
                let k = edge_key(a, b);
                edges.binary_search_by_key(&k, |e| e.0).ok()
            };
            let signs: Vec<i8> = val.iter().map(|&f| sign(f)).collect();
            let all_pos = |i: u32| -> (Point3<f64>, Point3<f64>) {
                let i = i as usize;
                if i < nv {
                    (ref_pos[i], pos[i])
                } else {
                    (cut_pos[i - nv], cut_pos[i - nv])
                }
            };
            let pieces: Vec<Result<Vec<[u32; 4]>, usize>> = tets
                .par_iter()
                .enumerate()
                .map(|(ti, t)| {
                    let s = t.map(|v| signs[v as usize]);
                    let mut out = Vec::new();
                    let cut = |a: u32, b: u32| -> u32 {
                        edge_index(a, b).map(|e| cut_id[e]).unwrap_or(u32::MAX)
                    };
                    // A tetrahedron with all four vertices warped onto the
                    // surface is kept when its centroid is inside (it fills a
                    // crease the lattice cannot follow); the proven mesher
                    // keeps it only within the proven bounds (the paper
                    // drops them all, which can pinch the surface at creases).
                    let keep_all_zero = s.iter().all(|&x| x == 0) && {
                        let w = t.map(|v| pos[v as usize]);
                        let c = w.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) / 4.0;
                        sdf.distance(&Point3::from(c)) < 0.0
                            && (!parity
                                || tet_dihedrals(&w).iter().all(|a| {
                                    (PROVEN_MIN_DIHEDRAL_DEG..=PROVEN_MAX_DIHEDRAL_DEG).contains(a)
                                }))
                    };
                    if parity && bcc.get(ti).copied().unwrap_or(false) {
                        parity::BccTet::new(*t, s, &coords, &cut).stencil(keep_all_zero, &mut out);
                    } else {
                        stencil(t, &s, keep_all_zero, &cut, &mut out);
                    }
                    for o in &mut out {
                        if o.contains(&u32::MAX) {
                            // A strictly crossing edge always keeps its cut point.
                            return Err(ti);
                        }
                        let r = o.map(|i| all_pos(i).0);
                        let w = o.map(|i| all_pos(i).1);
                        let vr = signed6(&r);
                        if vr < 0.0 {
                            o.swap(2, 3);
                        }
                        let vw = signed6(&w) * vr.signum();
                        if vr == 0.0 || vw <= 0.0 {
                            return Err(ti);
                        }
                    }
                    Ok(out)
                })
                .collect();
            let bad: Vec<usize> = pieces
                .iter()
                .filter_map(|p| p.as_ref().err().copied())
                .collect();
            if let Some(&first) = bad.first() {
                let mut changed = false;
                for &ti in &bad {
                    for &v in &tets[ti] {
                        if warped[v as usize] && !no_warp[v as usize] {
                            no_warp[v as usize] = true;
                            changed = true;
                        }
                    }
                }
                attempts += 1;
                if !changed || attempts > 8 {
                    return Err(StuffingError::Inverted { lattice_tet: first });
                }
                continue;
            }
            let mut out: Vec<[u32; 4]> = pieces.into_iter().flatten().flatten().collect();
            if out.is_empty() {
                return Err(StuffingError::NoInterior { spacing });
            }
            // Compact: keep used nodes only, in first-use order of their index.
            let total = nv + cut_pos.len();
            let mut map = vec![u32::MAX; total];
            for t in &out {
                for &v in t {
                    map[v as usize] = 0;
                }
            }
            let mut nodes = Vec::new();
            for (i, m) in map.iter_mut().enumerate() {
                if *m == 0 {
                    *m = nodes.len() as u32;
                    nodes.push(all_pos(i as u32).1);
                }
            }
            for t in &mut out {
                *t = t.map(|v| map[v as usize]);
            }
            return Ok(TetMesh::new(nodes, out)?);
        }
    }
}

pub(super) fn signed6(p: &[Point3<f64>; 4]) -> f64 {
    (p[1] - p[0]).cross(&(p[2] - p[0])).dot(&(p[3] - p[0]))
}

/// Appends the stuffing stencil of lattice tetrahedron `t` with vertex signs
/// `s` (cut points from `cut`); output orientation is fixed by the caller.
pub(super) fn stencil(
    t: &[u32; 4],
    s: &[i8; 4],
    keep_all_zero: bool,
    cut: &dyn Fn(u32, u32) -> u32,
    out: &mut Vec<[u32; 4]>,
) {
    let pick = |want: i8| -> Vec<u32> { (0..4).filter(|&i| s[i] == want).map(|i| t[i]).collect() };
    let (ins, zeros, outs) = (pick(-1), pick(0), pick(1));
    match (ins.len(), zeros.len(), outs.len()) {
        (0, 4, 0) => {
            if keep_all_zero {
                out.push(*t);
            }
        }
        (0, _, _) => {}
        (_, _, 0) => out.push(*t),
        (1, _, _) => {
            let a = ins[0];
            let mut v = vec![a];
            v.extend(&zeros);
            v.extend(outs.iter().map(|&b| cut(a, b)));
            out.push([v[0], v[1], v[2], v[3]]);
        }
        (2, 0, 2) => {
            let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
            prism([a, cut(a, c), cut(a, d)], [b, cut(b, c), cut(b, d)], out);
        }
        (2, 1, 1) => {
            let (a, b, z, c) = (ins[0], ins[1], zeros[0], outs[0]);
            pyramid([a, b, cut(b, c), cut(a, c)], z, out);
        }
        // The only count left with an inside and an outside vertex: (3, 0, 1).
        _ => {
            let (a, b, c, d) = (ins[0], ins[1], ins[2], outs[0]);
            prism([a, b, c], [cut(a, d), cut(b, d), cut(c, d)], out);
        }
    }
}

/// Splits the pyramid with base `b` (cyclic) and apex `z` by the base diagonal
/// through the base vertex of smallest index.
fn pyramid(b: [u32; 4], z: u32, out: &mut Vec<[u32; 4]>) {
    let m = *b.iter().min().unwrap_or(&b[0]);
    if m == b[0] || m == b[2] {
        out.push([z, b[0], b[1], b[2]]);
        out.push([z, b[0], b[2], b[3]]);
    } else {
        out.push([z, b[1], b[2], b[3]]);
        out.push([z, b[1], b[3], b[0]]);
    }
}

/// Splits the prism with triangles `p`, `q` (`p[i] - q[i]` its lateral edges)
/// into three tetrahedra, each quadrilateral split by the diagonal through its
/// vertex of smallest index.
pub(super) fn prism(p: [u32; 3], q: [u32; 3], out: &mut Vec<[u32; 4]>) {
    let all = [p[0], p[1], p[2], q[0], q[1], q[2]];
    let (mi, _) = all
        .iter()
        .enumerate()
        .min_by_key(|(_, v)| **v)
        .unwrap_or((0, &all[0]));
    let (p, q) = if mi < 3 { (p, q) } else { (q, p) };
    let r = mi % 3;
    let p = [p[r], p[(r + 1) % 3], p[(r + 2) % 3]];
    let q = [q[r], q[(r + 1) % 3], q[(r + 2) % 3]];
    // p[0] is the smallest: the tetrahedron at p[0] with the opposite triangle.
    out.push([p[0], q[0], q[1], q[2]]);
    // The pyramid p[0] + quad (p1, p2, q2, q1).
    pyramid([p[1], p[2], q[2], q[1]], p[0], out);
}
