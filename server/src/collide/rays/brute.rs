//! The paper's brute force: every source-node line against every surface
//! triangle, in parallel over the nodes (rayon). The reference that every other
//! [`RayBackend`] must match exactly.

use super::ray::{PreparedRay, RayTest};
use super::{Hit, NodeHits, RayBackend, SurfaceError, check_surface};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// Folds one hit into a node's answers. Nearest means smallest `|t|`; equal
/// `|t|` is broken by the smaller triangle index, so that every backend gives
/// the same answer whatever order it visits the triangles in. `t <= 0` is
/// behind, `t > 0` in front.
#[inline]
pub fn keep_nearest(hits: &mut NodeHits, hit: Hit) {
    let slot = if hit.t <= 0.0 {
        &mut hits.behind
    } else {
        &mut hits.front
    };
    let better = match slot {
        None => true,
        Some(old) => {
            let (a, b) = (hit.t.abs(), old.t.abs());
            a < b || (a == b && hit.triangle < old.triangle)
        }
    };
    if better {
        *slot = Some(hit);
    }
}

/// Nearest hits behind and in front of the line `origin + t dir` over every
/// triangle of `triangles` (indices into `positions`, which must cover them):
/// the reference answer of one source node. Every backend's answer for a line
/// is this one, bit for bit (the GPU backends call it to settle the rays their
/// `f32` filter cannot).
pub fn cast_line(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
    test: RayTest,
    origin: Point3<f64>,
    dir: Vector3<f64>,
) -> NodeHits {
    let ray = PreparedRay::new(test, origin, dir);
    let mut hits = NodeHits::default();
    for (i, tri) in triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|v| &positions[v as usize]);
        if let Some(h) = ray.intersect(a, b, c) {
            keep_nearest(
                &mut hits,
                Hit {
                    triangle: i as u32,
                    t: h.t,
                    u: h.u,
                    v: h.v,
                },
            );
        }
    }
    hits
}

/// Brute-force backend (CPU).
#[derive(Debug, Clone)]
pub struct BruteForce {
    triangles: Vec<[u32; 3]>,
    positions: Vec<Point3<f64>>,
    test: RayTest,
    /// One more than the largest vertex index; positions shorter than this
    /// leave the backend answering no hits until valid positions arrive.
    needed: usize,
}

impl BruteForce {
    /// A backend over `triangles` (indices into the positions given to
    /// [`RayBackend::update_positions`]), using the watertight test.
    pub fn new(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Result<Self, SurfaceError> {
        Self::with_test(triangles, positions, RayTest::Watertight)
    }

    /// As [`BruteForce::new`] with a chosen ray-triangle test.
    pub fn with_test(
        triangles: &[[u32; 3]],
        positions: &[Point3<f64>],
        test: RayTest,
    ) -> Result<Self, SurfaceError> {
        let needed = check_surface(triangles, positions)?;
        Ok(Self {
            triangles: triangles.to_vec(),
            positions: positions.to_vec(),
            test,
            needed,
        })
    }
}

impl RayBackend for BruteForce {
    fn method(&self) -> &'static str {
        "brute"
    }

    fn backend(&self) -> &'static str {
        "cpu"
    }

    fn update_positions(&mut self, positions: &[Point3<f64>]) {
        self.positions.clear();
        self.positions.extend_from_slice(positions);
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let n = origins.len().min(dirs.len());
        out.clear();
        out.resize(n, NodeHits::default());
        if self.positions.len() < self.needed {
            return;
        }
        let this = &*self;
        out.par_iter_mut()
            .zip(origins[..n].par_iter().zip(dirs[..n].par_iter()))
            .for_each(|(slot, (o, d))| {
                *slot = cast_line(&this.triangles, &this.positions, this.test, *o, *d)
            });
    }
}
