//! Refinement of the background lattice to a size field: a tetrahedron
//! whose longest edge is longer than the size asked at its centroid is
//! bisected at that edge, after every tetrahedron around the edge whose own
//! longest edge is another one (so the lattice stays conforming); down to
//! the finest lattice edge, `h`.

use super::{Background, SizeField, TET_EDGES, edge_key, key_ends};
use crate::mesh::sdf::Sdf;
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;

impl Background {
    pub(super) fn refine(&mut self, sdf: &dyn Sdf, size: &dyn SizeField) {
        let mut r = Refiner {
            alive: vec![true; self.tets.len()],
            edge_tets: HashMap::with_capacity(self.tets.len() * 2),
            mids: HashMap::new(),
        };
        for (ti, t) in self.tets.iter().enumerate() {
            for &(i, j) in &TET_EDGES {
                r.edge_tets
                    .entry(edge_key(t[i], t[j]))
                    .or_default()
                    .push(ti as u32);
            }
        }
        let fine2 = {
            let l = 2i64; // finest black edge: h = 2 units
            l * l
        };
        let mut queue: Vec<u32> = (0..self.tets.len() as u32).rev().collect();
        while let Some(ti) = queue.pop() {
            if !r.alive[ti as usize] {
                continue;
            }
            let t = self.tets[ti as usize];
            let (l2, _) = TET_EDGES
                .iter()
                .map(|&(i, j)| (self.len2(t[i], t[j]), 0))
                .max()
                .unwrap_or((0, 0));
            if l2 <= fine2 {
                continue;
            }
            let c = t.iter().fold(Vector3::zeros(), |s, &i| {
                s + self.position(&self.coords[i as usize]).coords
            }) / 4.0;
            let c = Point3::from(c);
            let want = size.size(&c, sdf.distance(&c)) / self.unit;
            if (l2 as f64) <= want * want * (1.0 + 1e-9) {
                continue;
            }
            let first_new = self.tets.len();
            self.refine_tet(sdf, &mut r, ti);
            queue.extend((first_new as u32..self.tets.len() as u32).rev());
        }
        let tets = std::mem::take(&mut self.tets);
        self.tets = tets
            .into_iter()
            .zip(r.alive)
            .filter(|(_, a)| *a)
            .map(|(t, _)| t)
            .collect();
    }

    /// Bisects `ti` at its longest edge, first bisecting (recursively) every
    /// tetrahedron around that edge whose longest edge is another one.
    fn refine_tet(&mut self, sdf: &dyn Sdf, r: &mut Refiner, ti: u32) {
        while r.alive[ti as usize] {
            let e = self.longest(&self.tets[ti as usize]);
            let around = r.edge_tets.get(&e).cloned().unwrap_or_default();
            let mut ready = true;
            for t2 in around {
                if self.longest(&self.tets[t2 as usize]) != e {
                    ready = false;
                    self.refine_tet(sdf, r, t2);
                }
            }
            if ready {
                self.bisect(sdf, r, e);
            }
        }
    }

    fn bisect(&mut self, sdf: &dyn Sdf, r: &mut Refiner, e: u64) {
        let (a, b) = key_ends(e);
        let m = *r.mids.entry(e).or_insert_with(|| {
            let (p, q) = (self.coords[a as usize], self.coords[b as usize]);
            debug_assert!(
                (0..3).all(|i| (p[i] + q[i]) % 2 == 0),
                "midpoint off the finest lattice"
            );
            let c = [(p[0] + q[0]) / 2, (p[1] + q[1]) / 2, (p[2] + q[2]) / 2];
            self.coords.push(c);
            let pos = self.position(&c);
            self.values.push(sdf.distance(&pos));
            (self.coords.len() - 1) as u32
        });
        let around = r.edge_tets.remove(&e).unwrap_or_default();
        for ti in around {
            let t = self.tets[ti as usize];
            r.alive[ti as usize] = false;
            for &(i, j) in &TET_EDGES {
                let k = edge_key(t[i], t[j]);
                if k != e
                    && let Some(v) = r.edge_tets.get_mut(&k)
                {
                    v.retain(|&x| x != ti);
                }
            }
            for (from, to) in [(b, m), (a, m)] {
                // Replacing one end of the bisected edge by its midpoint keeps
                // the orientation (the volume halves).
                let child = t.map(|v| if v == from { to } else { v });
                let ci = self.tets.len() as u32;
                self.tets.push(child);
                r.alive.push(true);
                for &(i, j) in &TET_EDGES {
                    r.edge_tets
                        .entry(edge_key(child[i], child[j]))
                        .or_default()
                        .push(ci);
                }
            }
        }
    }
}

struct Refiner {
    alive: Vec<bool>,
    edge_tets: HashMap<u64, Vec<u32>>,
    mids: HashMap<u64, u32>,
}
