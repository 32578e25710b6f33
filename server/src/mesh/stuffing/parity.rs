//! Labelle & Shewchuk's stencils for cut BCC tetrahedra.
//!
//! A cut BCC tetrahedron whose inside part has a quadrilateral face (vertex
//! signs `- - 0 +`, `- - - +` or `- - + +`) is split by fixed diagonal
//! choices that the paper's angle proof relies on. Every face of a BCC
//! tetrahedron has one black edge (length `H`) and two red ones; a
//! quadrilateral lies on a face with two inside vertices `a`, `b` and an
//! outside apex `t`, between `a`, `b` and the cut points `c_a` on `t a`,
//! `c_b` on `t b`:
//!
//! * when a cut edge is black, the diagonal joins its cut point to the other
//!   inside vertex (`t a` black: `b c_a`);
//! * when `a b` is black, the **parity rule** decides: with `wz = 1` if `a b`
//!   joins grid points (not cell centres) and `g` the number of coordinates
//!   in which `a` exceeds `c_b`, the diagonal is `b c_a` if `wz + g` is odd,
//!   `a c_b` otherwise. `g` does not depend on where `c_b` lies inside `t b`,
//!   so the rule is evaluated exactly at the edge midpoint in integer lattice
//!   coordinates. Swapping `a` and `b` flips the parity of `g`, so both
//!   tetrahedra sharing the face make the same choice.
//!
//! The quadrilateral of cut points inside a `- - + +` tetrahedron is split by
//! the diagonal that leaves the prism decomposable into three tetrahedra
//! (with the face diagonals above it is unique, except in configurations the
//! face rules leave open, where the diagonal joining the cut points on black
//! edges is taken).

use super::{TET_EDGES, lattice_len2, stencil};

/// Lattice data one stencil needs: exact integer coordinates (units of half
/// the finest spacing) and cut point ids.
pub(super) struct BccTet<'a> {
    /// The four lattice vertices.
    t: [u32; 4],
    /// Their signs after warping.
    s: [i8; 4],
    /// Integer coordinates of every lattice vertex.
    coords: &'a [[i32; 3]],
    /// The cut point on lattice edge `(a, b)` (`u32::MAX` when none).
    cut: &'a dyn Fn(u32, u32) -> u32,
    /// Squared length of the tetrahedron's black edges.
    black: i64,
}

impl<'a> BccTet<'a> {
    pub fn new(
        t: [u32; 4],
        s: [i8; 4],
        coords: &'a [[i32; 3]],
        cut: &'a dyn Fn(u32, u32) -> u32,
    ) -> Self {
        let black = TET_EDGES
            .iter()
            .map(|&(i, j)| lattice_len2(coords, t[i], t[j]))
            .max()
            .unwrap_or(0);
        Self {
            t,
            s,
            coords,
            cut,
            black,
        }
    }

    fn len2(&self, a: u32, b: u32) -> i64 {
        lattice_len2(self.coords, a, b)
    }

    /// The diagonal splitting the quadrilateral on face `(a, b, apex)`, where
    /// `a`, `b` are inside and `apex` outside (see the module docs).
    pub fn face_diagonal(&self, a: u32, b: u32, apex: u32) -> (u32, u32) {
        let black = self.black;
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        let cut = self.cut;
        if self.len2(apex, a) == black {
            return (b, cut(apex, a));
        }
        if self.len2(apex, b) == black {
            return (a, cut(apex, b));
        }
        if parity_odd(self.coords, a, b, apex) {
            (b, cut(apex, a))
        } else {
            (a, cut(apex, b))
        }
    }

    /// Appends the inside part of the tetrahedron as tetrahedra.
    pub fn stencil(&self, keep_all_zero: bool, out: &mut Vec<[u32; 4]>) {
        let (t, s) = (self.t, self.s);
        let pick =
            |want: i8| -> Vec<u32> { (0..4).filter(|&i| s[i] == want).map(|i| t[i]).collect() };
        let (ins, zeros, outs) = (pick(-1), pick(0), pick(1));
        let cut = self.cut;
        match (ins.len(), zeros.len(), outs.len()) {
            (2, 1, 1) => {
                let (a, b, z, c) = (ins[0], ins[1], zeros[0], outs[0]);
                let d = self.face_diagonal(a, b, c);
                pyramid_with([a, b, cut(b, c), cut(a, c)], z, d, out);
            }
            (3, 0, 1) => {
                let d = outs[0];
                let p = [ins[0], ins[1], ins[2]];
                let q = p.map(|v| cut(v, d));
                let diags = [0, 1, 2].map(|i| self.face_diagonal(p[i], p[(i + 1) % 3], d));
                if !prism_with(p, q, diags, out) {
                    stencil(&t, &s, keep_all_zero, cut, out);
                }
            }
            (2, 0, 2) => {
                let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
                let (ac, ad, bc, bd) = (cut(a, c), cut(a, d), cut(b, c), cut(b, d));
                let p = [a, ac, ad];
                let q = [b, bc, bd];
                let d0 = self.face_diagonal(a, b, c);
                let d2 = self.face_diagonal(a, b, d);
                // Prefer the surface diagonal joining the cut points on black
                // edges; the other one when that leaves the prism cyclic.
                let first = if self.len2(a, d) == self.black {
                    (ad, bc)
                } else {
                    (ac, bd)
                };
                let second = if first == (ac, bd) {
                    (ad, bc)
                } else {
                    (ac, bd)
                };
                let mut tmp = Vec::with_capacity(3);
                if prism_with(p, q, [d0, first, d2], &mut tmp)
                    || prism_with(p, q, [d0, second, d2], &mut tmp)
                {
                    out.extend(tmp);
                } else {
                    stencil(&t, &s, keep_all_zero, cut, out);
                }
            }
            _ => stencil(&t, &s, keep_all_zero, cut, out),
        }
    }
}

/// The parity rule for the face `(a, b, apex)` with black edge `a b`: true
/// when the diagonal is `b c_a`.
pub(super) fn parity_odd(coords: &[[i32; 3]], a: u32, b: u32, apex: u32) -> bool {
    let (pa, pb, pt) = (
        coords[a as usize],
        coords[b as usize],
        coords[apex as usize],
    );
    // Grid points have even coordinates, cell centres odd ones.
    let wz = usize::from(pa[0].rem_euclid(2) == 0);
    // Coordinates in which a exceeds the midpoint of apex-b (doubled).
    let g = (0..3)
        .filter(|&i| 2 * i64::from(pa[i]) > i64::from(pt[i]) + i64::from(pb[i]))
        .count();
    (wz + g) % 2 == 1
}

fn same(d: (u32, u32), u: u32, v: u32) -> bool {
    d == (u, v) || d == (v, u)
}

/// Splits the pyramid with cyclic base `q` and apex `z` along diagonal `d`.
fn pyramid_with(q: [u32; 4], z: u32, d: (u32, u32), out: &mut Vec<[u32; 4]>) {
    if same(d, q[0], q[2]) {
        out.push([z, q[0], q[1], q[2]]);
        out.push([z, q[0], q[2], q[3]]);
    } else {
        out.push([z, q[1], q[2], q[3]]);
        out.push([z, q[1], q[3], q[0]]);
    }
}

/// Splits the prism with triangles `p`, `q` (lateral edges `p_i q_i`) into
/// three tetrahedra using diagonal `diags[i]` on quadrilateral
/// `(p_i, p_i+1, q_i+1, q_i)`. False (nothing appended) when the diagonals are
/// cyclic, which no decomposition without a new vertex can honour.
fn prism_with(p: [u32; 3], q: [u32; 3], diags: [(u32, u32); 3], out: &mut Vec<[u32; 4]>) -> bool {
    for (x, y) in [(p, q), (q, p)] {
        for r in 0..3 {
            let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
            // Vertex x_r carries the diagonals of both quadrilaterals at it.
            if same(diags[r], x[r], y[r1]) && same(diags[r2], x[r], y[r2]) {
                out.push([x[r], y[r], y[r1], y[r2]]);
                pyramid_with([x[r1], x[r2], y[r2], y[r1]], x[r], diags[r1], out);
                return true;
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The BCC tetrahedra of a 2x2x2 block of cells (grid points even,
    /// centres odd coordinates).
    fn block() -> (Vec<[i32; 3]>, Vec<[u32; 4]>) {
        let mut coords = vec![];
        let mut id = std::collections::HashMap::new();
        let mut node = |c: [i32; 3], coords: &mut Vec<[i32; 3]>| -> u32 {
            *id.entry(c).or_insert_with(|| {
                coords.push(c);
                (coords.len() - 1) as u32
            })
        };
        let mut tets = vec![];
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for a in 0..2 {
                for b in 0..2 {
                    let mut c1 = [0; 3];
                    c1[axis] = 1;
                    c1[u] = 2 * a + 1;
                    c1[v] = 2 * b + 1;
                    let mut c2 = c1;
                    c2[axis] = 3;
                    let corner = |da: i32, db: i32| {
                        let mut g = [0; 3];
                        g[axis] = 2;
                        g[u] = 2 * a + 2 * da;
                        g[v] = 2 * b + 2 * db;
                        g
                    };
                    let q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                    for e in 0..4 {
                        let t = [q[e], q[(e + 1) % 4], c1, c2].map(|c| node(c, &mut coords));
                        tets.push(t);
                    }
                }
            }
        }
        (coords, tets)
    }

    #[test]
    fn the_parity_rule_is_a_function_of_the_face() {
        // For every face of every BCC tetrahedron whose black edge is a b,
        // evaluating with a and b swapped picks the same diagonal.
        let (coords, tets) = block();
        let mut faces = 0;
        for t in &tets {
            let l2 = |a: u32, b: u32| -> i64 {
                let (p, q) = (coords[a as usize], coords[b as usize]);
                (0..3).map(|i| i64::from(p[i] - q[i]).pow(2)).sum()
            };
            for apex in 0..4 {
                let f: Vec<u32> = (0..4).filter(|&i| i != apex).map(|i| t[i]).collect();
                for (i, j) in [(0, 1), (0, 2), (1, 2)] {
                    let (a, b) = (f[i], f[j]);
                    if l2(a, b) != 4 {
                        continue;
                    }
                    let k = 3 - i - j;
                    let apex_v = f[k];
                    // Only faces where a b is the black edge: the apex edges are red.
                    assert_eq!(l2(apex_v, a), 3);
                    let one = parity_odd(&coords, a, b, apex_v);
                    let other = parity_odd(&coords, b, a, apex_v);
                    assert_ne!(one, other, "face {a} {b} apex {apex_v}");
                    faces += 1;
                }
            }
        }
        assert!(faces > 50, "{faces}");
    }

    #[test]
    fn random_sign_patterns_give_conforming_covers() {
        // Random signs on the block's vertices: the pieces of all tetrahedra
        // form a conforming mesh, so a triangle used by one piece only lies
        // on the isosurface (every vertex a cut point or a zero vertex) or on
        // the block's outer boundary. A quadrilateral split differently from
        // its two sides would leave triangles with an inside vertex used once.
        let (coords, tets) = block();
        let n = coords.len() as u32;
        let mut edges = std::collections::HashMap::new();
        for t in &tets {
            for &(i, j) in &TET_EDGES {
                let k = (t[i].min(t[j]), t[i].max(t[j]));
                let len = edges.len() as u32;
                edges.entry(k).or_insert(n + len);
            }
        }
        let cut = |a: u32, b: u32| edges[&(a.min(b), a.max(b))];
        let mut ends = vec![(0u32, 0u32); edges.len()];
        for (&k, &id) in &edges {
            ends[(id - n) as usize] = k;
        }
        // Faces of the lattice block used by one tetrahedron: its boundary.
        let mut lattice_faces: std::collections::HashMap<[u32; 3], u32> = Default::default();
        for t in &tets {
            for skip in 0..4 {
                let mut f: Vec<u32> = (0..4).filter(|&i| i != skip).map(|i| t[i]).collect();
                f.sort_unstable();
                *lattice_faces.entry([f[0], f[1], f[2]]).or_default() += 1;
            }
        }
        let outer: Vec<[u32; 3]> = lattice_faces
            .iter()
            .filter(|(_, c)| **c == 1)
            .map(|(f, _)| *f)
            .collect();
        // The lattice vertices a piece vertex lies on or between.
        let support = |v: u32| -> Vec<u32> {
            if v < n {
                vec![v]
            } else {
                let (a, b) = ends[(v - n) as usize];
                vec![a, b]
            }
        };
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        for _ in 0..3000 {
            let signs: Vec<i8> = (0..n).map(|_| (next() % 3) as i8 - 1).collect();
            let mut faces: std::collections::HashMap<[u32; 3], u32> = Default::default();
            for t in &tets {
                let s = t.map(|v| signs[v as usize]);
                let bt = BccTet::new(*t, s, &coords, &cut);
                let mut out = vec![];
                bt.stencil(false, &mut out);
                for o in &out {
                    for skip in 0..4 {
                        let mut f: Vec<u32> = (0..4).filter(|&i| i != skip).map(|i| o[i]).collect();
                        f.sort_unstable();
                        *faces.entry([f[0], f[1], f[2]]).or_default() += 1;
                    }
                }
            }
            for (f, &c) in &faces {
                assert!(c <= 2, "{f:?} used {c} times");
                if c == 2 {
                    continue;
                }
                let on_surface = f.iter().all(|&v| v >= n || signs[v as usize] == 0);
                let on_boundary = outer
                    .iter()
                    .any(|o| f.iter().flat_map(|&v| support(v)).all(|w| o.contains(&w)));
                assert!(on_surface || on_boundary, "open face {f:?}");
            }
        }
    }
}
