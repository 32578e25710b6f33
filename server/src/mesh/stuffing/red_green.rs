//! The graded BCC background of [`stuff_proven`](super::stuff_proven): red
//! refinement of BCC tetrahedra with green closure, fine and uniform wherever
//! the surface passes.
//!
//! # Red refinement
//! Splitting a BCC tetrahedron of black-edge length `H` at its six edge
//! midpoints gives four corner tetrahedra and an octahedron; cutting the
//! octahedron along the diagonal between the midpoints of the two black
//! edges gives four more. All eight are BCC tetrahedra of the lattice of
//! spacing `H / 2` (the parent's grid points and cell centres are grid points
//! of the half lattice, its edge midpoints the rest), so refining every
//! tetrahedron of a region reproduces the uniform BCC lattice there exactly.
//!
//! # Green closure
//! A tetrahedron left unrefined next to refined ones gets midpoints on some
//! of its edges. Exactly the three edges of one face: that face is split in
//! four as its red neighbour splits it, each piece joined to the opposite
//! vertex. A fully marked face with more marks: red. Otherwise no face is
//! fully marked, so no neighbour across a face is red, and the tetrahedron
//! is bisected at its marked edges one after another in the order of the
//! edges' global keys (every piece holding the edge splits in two): each
//! face is split by its own marked edges alone, and neighbours agree. Red
//! refinement marks more edges, so the closure repeats until nothing
//! changes. The pieces of a BCC tetrahedron have dihedral angles between 18.4
//! and 144.8 degrees whatever the pattern and order. Green pieces are never
//! refined again: a
//! red tetrahedron of the next level that would split an edge of a green
//! piece (or of a coarser unrefined tetrahedron) makes its ancestor red, and
//! the construction restarts with that ancestor forced.
//!
//! # The surface band
//! Every lattice vertex on a cut edge (or with a zero value) must have only
//! finest BCC tetrahedra around it: then each tetrahedron the stencils cut,
//! and each vertex warping moves, sees exactly the uniform lattice of the
//! paper's proof. The refinement criterion asks for it (a tetrahedron is
//! refined while its vertex values come within its black edge plus `h` of
//! zero), and a check after construction enforces it the same way as the
//! closure: by forcing the offending ancestors and restarting. Each restart
//! forces at least one more tetrahedron, so the loop ends.
//!
//! Why hand-written: see [`super`]; this replaces the paper's octree
//! transition stencils (half pyramids, bisected BCC tetrahedra) by standard
//! red-green closure, which needs no tables.

use super::{Background, Lattice, SizeField, StuffingError, TET_EDGES, edge_key};
use crate::mesh::sdf::Sdf;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

/// A tetrahedron named by its sorted integer vertex coordinates (the same
/// across restarts, unlike node ids).
type TetKey = [[i32; 3]; 4];

/// Most restarts of the construction before giving up.
const MAX_RESTARTS: usize = 64;

/// Every closure piece of a BCC tetrahedron has dihedral angles in
/// [[`GREEN_MIN_DIHEDRAL_DEG`], [`GREEN_MAX_DIHEDRAL_DEG`]]: the tests
/// enumerate all patterns under all bisection orders.
/// Smallest dihedral angle of a green closure piece, degrees.
pub const GREEN_MIN_DIHEDRAL_DEG: f64 = 18.4;
/// Largest dihedral angle of a green closure piece, degrees.
pub const GREEN_MAX_DIHEDRAL_DEG: f64 = 144.8;

/// What a non-red tetrahedron becomes, from its marked edges.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Closure {
    /// No marked edge: kept whole.
    Keep,
    /// Bisected at its marked edges (bit `e` for local edge `e`), none of its
    /// faces having all three edges marked.
    Green(u8),
    /// Exactly the three edges of the face opposite local vertex `k`: the
    /// face split in four as a red neighbour splits it, each piece joined to
    /// the opposite vertex.
    Face(usize),
    /// Refined red.
    Red,
}

/// Local edges of the face opposite each vertex.
const FACE_EDGES: [u8; 4] = {
    let mut m = [0u8; 4];
    let mut k = 0;
    while k < 4 {
        let mut e = 0;
        while e < 6 {
            let (i, j) = TET_EDGES[e];
            if i != k && j != k {
                m[k] |= 1 << e;
            }
            e += 1;
        }
        k += 1;
    }
    m
};

/// Whether all three edges of some face are in `mask`.
fn has_full_face(mask: u8) -> bool {
    for f in FACE_EDGES {
        if mask & f == f {
            return true;
        }
    }
    false
}

fn closure(t: &[u32; 4], marked: &HashSet<u64>) -> Closure {
    let mut mask = 0u8;
    for (e, &(i, j)) in TET_EDGES.iter().enumerate() {
        if marked.contains(&edge_key(t[i], t[j])) {
            mask |= 1 << e;
        }
    }
    if mask == 0 {
        return Closure::Keep;
    }
    if let Some(k) = (0..4).find(|&k| mask == FACE_EDGES[k]) {
        return Closure::Face(k);
    }
    if has_full_face(mask) {
        // A fully marked face next to more marks: only red matches it.
        return Closure::Red;
    }
    Closure::Green(mask)
}

/// The four pieces of `t` with the face opposite local vertex `k` split at
/// its edge midpoints.
fn split_face(t: &[u32; 4], k: usize, mid: &dyn Fn(u32, u32) -> u32) -> Vec<[u32; 4]> {
    let apex = t[k];
    let f: Vec<u32> = (0..4).filter(|&i| i != k).map(|i| t[i]).collect();
    let (a, b, c) = (f[0], f[1], f[2]);
    let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
    vec![
        [a, ab, ca, apex],
        [b, bc, ab, apex],
        [c, ca, bc, apex],
        [ab, bc, ca, apex],
    ]
}

/// Bisects `t` at the midpoints (from `mid`) of its edges in `mask`, one edge
/// after another in the order of their global keys: every piece holding the
/// edge is split in two. The split of each face depends only on the face's
/// marked edges and their keys, so neighbours agree.
fn bisect_marked(t: &[u32; 4], mask: u8, mid: &dyn Fn(u32, u32) -> u32) -> Vec<[u32; 4]> {
    let mut edges: Vec<(u64, u32, u32)> = TET_EDGES
        .iter()
        .enumerate()
        .filter(|(e, _)| mask & (1 << e) != 0)
        .map(|(_, &(i, j))| (edge_key(t[i], t[j]), t[i], t[j]))
        .collect();
    edges.sort_unstable();
    let mut pieces = vec![*t];
    for (_, a, b) in edges {
        let m = mid(a, b);
        let mut next = Vec::with_capacity(pieces.len() * 2);
        for p in pieces {
            match (
                p.iter().position(|&v| v == a),
                p.iter().position(|&v| v == b),
            ) {
                (Some(i), Some(j)) => {
                    let mut x = p;
                    x[i] = m;
                    let mut y = p;
                    y[j] = m;
                    next.push(x);
                    next.push(y);
                }
                _ => next.push(p),
            }
        }
        pieces = next;
    }
    pieces
}

struct Build<'a> {
    bg: Background,
    sdf: &'a dyn Sdf,
    cache: &'a mut HashMap<[i32; 3], f64>,
    mids: HashMap<u64, u32>,
}

impl Build<'_> {
    fn key(&self, t: &[u32; 4]) -> TetKey {
        let mut k = t.map(|v| self.bg.coords[v as usize]);
        k.sort_unstable();
        k
    }

    fn len2(&self, a: u32, b: u32) -> i64 {
        self.bg.len2(a, b)
    }

    /// Creates the midpoints of `edges` (evaluating the field in parallel).
    fn add_midpoints(&mut self, edges: &[u64]) {
        let mut new: Vec<(u64, [i32; 3])> = Vec::new();
        for &e in edges {
            if self.mids.contains_key(&e) {
                continue;
            }
            let (a, b) = super::key_ends(e);
            let (p, q) = (self.bg.coords[a as usize], self.bg.coords[b as usize]);
            debug_assert!((0..3).all(|i| (p[i] + q[i]) % 2 == 0));
            let c = [(p[0] + q[0]) / 2, (p[1] + q[1]) / 2, (p[2] + q[2]) / 2];
            self.mids.insert(e, u32::MAX);
            new.push((e, c));
        }
        let bg = &self.bg;
        let cache = &*self.cache;
        let sdf = self.sdf;
        let values: Vec<f64> = new
            .par_iter()
            .map(|(_, c)| {
                cache
                    .get(c)
                    .copied()
                    .unwrap_or_else(|| sdf.distance(&bg.position(c)))
            })
            .collect();
        for ((e, c), f) in new.into_iter().zip(values) {
            self.cache.insert(c, f);
            self.bg.coords.push(c);
            self.bg.values.push(f);
            self.mids.insert(e, (self.bg.coords.len() - 1) as u32);
        }
    }

    fn mid(&self, a: u32, b: u32) -> u32 {
        self.mids[&edge_key(a, b)]
    }

    /// The eight BCC children of BCC tetrahedron `t`.
    fn red(&self, t: &[u32; 4]) -> [[u32; 4]; 8] {
        let [a, b, c, d] = *t;
        let m = |x: u32, y: u32| self.mid(x, y);
        // The black edges are a pair of opposite edges.
        let black = TET_EDGES
            .iter()
            .map(|&(i, j)| self.len2(t[i], t[j]))
            .max()
            .unwrap_or(0);
        let (p, q, r, s) = if self.len2(a, b) == black {
            (a, b, c, d)
        } else if self.len2(a, c) == black {
            (a, c, b, d)
        } else {
            (a, d, b, c)
        };
        // Black edges p q and r s; the octahedron's diagonal joins their
        // midpoints, its equator is the cycle pr, ps, qs, qr.
        let (top, bottom) = (m(p, q), m(r, s));
        let ring = [m(p, r), m(p, s), m(q, s), m(q, r)];
        let mut out = [
            [a, m(a, b), m(a, c), m(a, d)],
            [b, m(b, a), m(b, c), m(b, d)],
            [c, m(c, a), m(c, b), m(c, d)],
            [d, m(d, a), m(d, b), m(d, c)],
            [top, bottom, ring[0], ring[1]],
            [top, bottom, ring[1], ring[2]],
            [top, bottom, ring[2], ring[3]],
            [top, bottom, ring[3], ring[0]],
        ];
        for o in &mut out {
            *o = self.bg.oriented(*o);
        }
        out
    }

    fn green(&self, t: &[u32; 4], how: Closure) -> Vec<[u32; 4]> {
        let out = match how {
            Closure::Green(mask) => bisect_marked(t, mask, &|a, b| self.mid(a, b)),
            Closure::Face(k) => split_face(t, k, &|a, b| self.mid(a, b)),
            Closure::Keep | Closure::Red => vec![*t],
        };
        out.into_iter().map(|o| self.bg.oriented(o)).collect()
    }
}

impl Background {
    /// The red-green graded BCC background for `lat`, graded inside by `size`.
    pub(super) fn red_green(
        sdf: &dyn Sdf,
        lat: &Lattice,
        size: &dyn SizeField,
    ) -> Result<Self, StuffingError> {
        // The coarse lattice and the field at midpoints are the same on every
        // restart: built and evaluated once.
        let coarse = Background::new(sdf, lat)?;
        let mut forced: HashSet<TetKey> = HashSet::new();
        let mut cache: HashMap<[i32; 3], f64> = HashMap::new();
        for _ in 0..MAX_RESTARTS {
            match Self::red_green_once(coarse.clone(), sdf, lat, size, &forced, &mut cache) {
                Ok(bg) => return Ok(bg),
                Err(more) => {
                    let before = forced.len();
                    forced.extend(more);
                    if forced.len() == before {
                        break;
                    }
                }
            }
        }
        Err(StuffingError::Grading {
            restarts: MAX_RESTARTS,
        })
    }

    /// One construction from the coarse lattice `bg`; `Err(keys)` names
    /// tetrahedra that must be refined.
    fn red_green_once(
        mut bg: Background,
        sdf: &dyn Sdf,
        lat: &Lattice,
        size: &dyn SizeField,
        forced: &HashSet<TetKey>,
        cache: &mut HashMap<[i32; 3], f64>,
    ) -> Result<Self, Vec<TetKey>> {
        let h = lat.spacing;
        let mut active = std::mem::take(&mut bg.tets);
        let mut b = Build {
            bg,
            sdf,
            cache,
            mids: HashMap::new(),
        };
        // Leaves: tetrahedron, whether it is a BCC tetrahedron, and the BCC
        // tetrahedron it came from.
        let mut leaves: Vec<([u32; 4], bool, [u32; 4])> = Vec::new();
        // Edges of leaves above the finest level -> their ancestor.
        let mut frozen: HashMap<u64, [u32; 4]> = HashMap::new();
        for level in 0..lat.levels {
            let black_units = 2i64 << (lat.levels - level);
            let black = black_units as f64 * b.bg.unit;
            let bgr = &b.bg;
            let mut red: Vec<bool> = active
                .par_iter()
                .map(|t| {
                    let f = t.map(|v| bgr.values[v as usize]);
                    let crosses = f.iter().any(|&x| x <= 0.0) && f.iter().any(|&x| x >= 0.0);
                    let nearest = f
                        .iter()
                        .copied()
                        .min_by(|x, y| x.abs().total_cmp(&y.abs()))
                        .unwrap_or(0.0);
                    if crosses || nearest.abs() < black + h {
                        return true;
                    }
                    let c = t.iter().fold(Vector3::zeros(), |s, &v| {
                        s + bgr.position(&bgr.coords[v as usize]).coords
                    }) / 4.0;
                    if size.size(&Point3::from(c), nearest) < black * (1.0 - 1e-9) {
                        return true;
                    }
                    let mut k = t.map(|v| bgr.coords[v as usize]);
                    k.sort_unstable();
                    forced.contains(&k)
                })
                .collect();
            // Green closure, to a fixed point: a tetrahedron turned red marks
            // its edges at once.
            let mut marked: HashSet<u64> = HashSet::new();
            let mark = |t: &[u32; 4], marked: &mut HashSet<u64>| {
                for &(i, j) in &TET_EDGES {
                    marked.insert(edge_key(t[i], t[j]));
                }
            };
            for (t, _) in active.iter().zip(&red).filter(|(_, r)| **r) {
                mark(t, &mut marked);
            }
            let mut changed = true;
            while changed {
                changed = false;
                for (k, t) in active.iter().enumerate() {
                    if !red[k] && closure(t, &marked) == Closure::Red {
                        red[k] = true;
                        mark(t, &mut marked);
                        changed = true;
                    }
                }
            }
            // A red tetrahedron may not split an edge of a coarser leaf.
            let mut violations: Vec<TetKey> = marked
                .iter()
                .filter_map(|e| frozen.get(e))
                .map(|anc| b.key(anc))
                .collect();
            if !violations.is_empty() {
                violations.sort_unstable();
                violations.dedup();
                return Err(violations);
            }
            // Midpoints in key order, so node ids do not depend on hashing.
            let mut edges: Vec<u64> = marked.iter().copied().collect();
            edges.sort_unstable();
            b.add_midpoints(&edges);
            let mut next = Vec::with_capacity(active.len() * 4);
            for (k, t) in active.iter().enumerate() {
                if red[k] {
                    next.extend(b.red(t));
                    continue;
                }
                let how = closure(t, &marked);
                let pieces = b.green(t, how);
                let bcc = how == Closure::Keep;
                for p in pieces {
                    for &(i, j) in &TET_EDGES {
                        frozen.insert(edge_key(p[i], p[j]), *t);
                    }
                    leaves.push((p, bcc, *t));
                }
            }
            active = next;
        }
        leaves.extend(active.into_iter().map(|t| (t, true, t)));
        // The surface band: vertices on cut edges or at zero see only finest
        // BCC tetrahedra.
        let values = &b.bg.values;
        let mut on_surface = vec![false; values.len()];
        for (t, _, _) in &leaves {
            for &(i, j) in &TET_EDGES {
                let (fa, fb) = (values[t[i] as usize], values[t[j] as usize]);
                if fa * fb < 0.0 {
                    on_surface[t[i] as usize] = true;
                    on_surface[t[j] as usize] = true;
                }
            }
            for &v in t {
                if values[v as usize] == 0.0 {
                    on_surface[v as usize] = true;
                }
            }
        }
        let mut violations: Vec<TetKey> = leaves
            .iter()
            .filter(|(t, bcc, _)| {
                let finest = *bcc && TET_EDGES.iter().all(|&(i, j)| b.len2(t[i], t[j]) <= 4);
                !finest && t.iter().any(|&v| on_surface[v as usize])
            })
            .map(|(_, _, anc)| b.key(anc))
            .collect();
        if !violations.is_empty() {
            violations.sort_unstable();
            violations.dedup();
            return Err(violations);
        }
        let mut bg = b.bg;
        bg.bcc = leaves.iter().map(|l| l.1).collect();
        bg.tets = leaves.into_iter().map(|l| l.0).collect();
        bg.parity = true;
        Ok(bg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn red_refinement_gives_the_half_lattice() {
        // A BCC tetrahedron in units of h / 2 at spacing 4 (grid points at
        // multiples of 4, centres at 2 mod 4): its eight children have the
        // BCC shape (two black edges of length 2 on opposite sides, four red
        // edges of squared length 3), fill it, and have their black edges on
        // one sublattice each (both ends even or both odd).
        let lat = Lattice {
            spacing: 1.0,
            levels: 1,
            anchor: Point3::origin(),
            bounds: crate::mesh::sdf::Aabb {
                lo: Point3::origin(),
                hi: Point3::new(4.0, 4.0, 4.0),
            },
        };
        let all_inside = |_: &Point3<f64>| -1.0;
        let bg = Background::new(&all_inside, &lat).expect("lattice");
        let mut cache = HashMap::new();
        let mut b = Build {
            bg,
            sdf: &all_inside,
            cache: &mut cache,
            mids: HashMap::new(),
        };
        let t = b.bg.tets[0];
        let edges: Vec<u64> = TET_EDGES
            .iter()
            .map(|&(i, j)| edge_key(t[i], t[j]))
            .collect();
        b.add_midpoints(&edges);
        let kids = b.red(&t);
        let vol = |t: &[u32; 4]| b.bg.orient_i(t);
        assert_eq!(kids.iter().map(vol).sum::<i64>(), vol(&t));
        for k in &kids {
            assert_eq!(vol(k) * 8, vol(&t));
            let mut l: Vec<i64> = TET_EDGES.iter().map(|&(i, j)| b.len2(k[i], k[j])).collect();
            l.sort_unstable();
            assert_eq!(l, vec![3, 3, 3, 3, 4, 4], "{k:?}");
            for &(i, j) in &TET_EDGES {
                if b.len2(k[i], k[j]) == 4 {
                    let (p, q) = (b.bg.coords[k[i] as usize], b.bg.coords[k[j] as usize]);
                    assert_eq!(p[0].rem_euclid(2), q[0].rem_euclid(2));
                    assert!((0..3).all(|c| p[c].rem_euclid(2) == p[0].rem_euclid(2)));
                }
            }
        }
    }

    #[test]
    fn green_pieces_of_a_bcc_tetrahedron_keep_bounded_angles() {
        // Every pattern of up to MAX_GREEN_EDGES marked edges, under every
        // labelling of the four vertices (which sets the bisection order).
        let base = [[0, 0, 0], [4, 0, 0], [2, 2, 2], [2, -2, 2]]
            .map(|c: [i32; 3]| Point3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2])));
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        let mut perms = vec![];
        for a in 0..4u32 {
            for b in 0..4u32 {
                for c in 0..4u32 {
                    for d in 0..4u32 {
                        let p = [a, b, c, d];
                        if (0..4).all(|i| (0..i).all(|j| p[i] != p[j])) {
                            perms.push(p);
                        }
                    }
                }
            }
        }
        for perm in perms {
            for mask in 1u8..64 {
                let face = (0..4).find(|&k| mask == FACE_EDGES[k]);
                if face.is_none() && has_full_face(mask) {
                    continue; // red
                }
                // Node ids: the labelling; midpoints get ids 4.. by edge.
                let mut pos: Vec<Point3<f64>> = vec![Point3::origin(); 4];
                for (k, &id) in perm.iter().enumerate() {
                    pos[id as usize] = base[k];
                }
                let mids: HashMap<u64, u32> = TET_EDGES
                    .iter()
                    .enumerate()
                    .map(|(e, &(i, j))| (edge_key(i as u32, j as u32), 4 + e as u32))
                    .collect();
                for &(i, j) in &TET_EDGES {
                    pos.push(Point3::from((pos[i].coords + pos[j].coords) / 2.0));
                }
                let t = [0u32, 1, 2, 3];
                let mid = |a: u32, b: u32| mids[&edge_key(a, b)];
                let pieces = match face {
                    Some(k) => split_face(&t, k, &mid),
                    None => bisect_marked(&t, mask, &mid),
                };
                let mut vol = 0.0;
                for p in &pieces {
                    let w = p.map(|v| pos[v as usize]);
                    vol += super::super::signed6(&w).abs();
                    for a in super::super::tet_dihedrals(&w) {
                        lo = lo.min(a);
                        hi = hi.max(a);
                    }
                }
                let whole = super::super::signed6(&t.map(|v| pos[v as usize])).abs();
                assert!((vol - whole).abs() < 1e-9 * whole, "mask {mask:b}");
            }
        }
        println!("green pieces: dihedral {lo:.3} .. {hi:.3} degrees");
        assert!(
            lo >= GREEN_MIN_DIHEDRAL_DEG && hi <= GREEN_MAX_DIHEDRAL_DEG,
            "{lo} {hi}"
        );
    }

    #[test]
    fn closure_patterns() {
        let t = [0u32, 1, 2, 3];
        let set = |es: &[(u32, u32)]| -> HashSet<u64> {
            es.iter().map(|&(a, b)| edge_key(a, b)).collect()
        };
        assert_eq!(closure(&t, &set(&[])), Closure::Keep);
        assert_eq!(closure(&t, &set(&[(2, 1)])), Closure::Green(1 << 3));
        assert_eq!(
            closure(&t, &set(&[(0, 1), (2, 3)])),
            Closure::Green(0b100001)
        );
        assert_eq!(
            closure(&t, &set(&[(0, 1), (1, 2), (0, 2)])),
            Closure::Face(3)
        );
        assert_eq!(
            closure(&t, &set(&[(0, 1), (1, 2), (0, 2), (2, 3)])),
            Closure::Red
        );
    }
}
