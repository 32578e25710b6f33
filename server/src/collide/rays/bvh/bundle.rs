//! Bundled traversal: one walk of the tree for a whole run of parallel rays.
//!
//! # Method
//! The rays of one spatula face share one direction `d` (bitwise equal) and
//! their origins lie on a grid in the face's plane. A run of at least
//! [`BUNDLE_MIN`] such consecutive rays is cast as one bundle:
//!
//! 0. A side of a ray that looks without bound (a whole line) is clipped to
//!    the bundle's reach `R`, [`LINE_REACH`] times the longer side of the
//!    origins' rectangle. The nearest hit of a side within `[0, R]` is the
//!    nearest of the whole side when it lies there ([`RayRange::clip`]); a
//!    clipped side that finds nothing within `R` is
//!    cast again alone by the caller, that side only, with the ray's own
//!    bound, skipping every box within `R` of the origin on that side
//!    ([`BundleCast`]), so answers do not depend on `R`, only the work
//!    does.
//!
//! 1. The origins are projected onto two vectors `e1`, `e2` perpendicular to
//!    `d` (m, in the plane of the face) and counting-sorted into a 2D grid of
//!    buckets over their bounding rectangle, about two rays a bucket.
//! 2. The tree is walked once with the swept volume of the bundle: a node is
//!    entered when its box meets the box of all the rays' segments (the
//!    [`super::Entry`] box, rounded outwards to the nodes' `f32`) and its
//!    projection onto `e1`, `e2` meets the origins' rectangle, i.e. the prism
//!    of the rectangle swept along `d` over the reach.
//! 3. Each triangle of a reached leaf is projected the same way; only the rays
//!    of the buckets its projected rectangle (widened far above rounding)
//!    overlaps, and among them only those whose own projected origin lies in
//!    that rectangle (four comparisons) and within the margin of the
//!    projected triangle itself (three edge functions, [`edge_filter`]; about
//!    half the rectangle's rays fall outside a triangle) are tested, with the
//!    watertight test of [`WatertightRay`] on the same `f64` positions as
//!    [`Bvh::cast_one`], and each hit within the ray's range is folded with
//!    [`keep_nearest`]. The rays share one prepared line (the permutation and
//!    the shear depend on the direction alone) and, per triangle, one
//!    evaluation of the degeneracy and parallelism rejection (a function of
//!    the direction and the triangle): the same operations on the same
//!    values as a ray prepared alone, so the same bits.
//!
//! A ray meets a triangle only where its line passes through it, so its
//! origin projects into the triangle's projected rectangle (up to a rounding
//! of `|t| |P d| + |P x| 1e-16`, far below the margin `1e-9 (|P x| + reach) +
//! 1 pm`), and the hit lies in the segment box and in the leaf's box: every
//! triangle that can give a ray a hit within its range is tested for it. The
//! nearest hit under [`keep_nearest`]'s order (smallest `|t|`, then smallest
//! triangle index) does not depend on the order the triangles are tested in,
//! so the answers are those of the per-ray cast and of the brute force, bit
//! for bit.
//!
//! # Why hand-written
//! Packet and frustum traversals of general ray tracers (Embree's streams,
//! parry3d's BVH) answer half rays with one best hit and their own triangle
//! test; the collision method needs the nearest hit behind and in front on a
//! line, with our watertight test and tie rule, over our refitted tree. The
//! bundle turns the per-ray walk of the top levels and the box tests near the
//! leaves into one walk and a bucket look-up per triangle.
//!
//! Buffers live in a per-thread workspace that grows to the largest bundle
//! and is reused: a cast allocates nothing once it has grown.

use super::{Bvh, round_down, round_up, segment};
use crate::collide::rays::brute::keep_nearest;
use crate::collide::rays::ray::{RayTest, WatertightRay, degenerate_or_parallel, moller_trumbore};
use crate::collide::{Hit, NodeHits, RayRange};
use nalgebra::{Point3, Vector3};
use std::cell::RefCell;

/// Fewest consecutive parallel rays cast as a bundle; shorter runs are cast
/// ray by ray (a bundle of ~30 rays measured slower than per-ray).
pub const BUNDLE_MIN: usize = 64;

/// How [`Bvh`] casts runs of rays with bitwise-equal directions (a scene's
/// `collision.traversal`: `"bundled"` or `"per-ray"`). Answers are identical
/// either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Traversal {
    /// Every ray walks the tree on its own.
    PerRay,
    /// Runs of at least [`BUNDLE_MIN`] rays walk it once, as a bundle
    /// (module documentation); shorter runs per ray.
    #[default]
    Bundled,
}

impl Traversal {
    /// The name a scene file gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::PerRay => "per-ray",
            Self::Bundled => "bundled",
        }
    }
}

/// Scratch of one thread's bundles (reused; grows to the largest bundle).
#[derive(Default)]
struct Workspace {
    /// The rays' ranges with unbounded sides clipped to the reach, m.
    ranges: Vec<RayRange>,
    /// Projected origins `(e1 . o, e2 . o)`, m.
    uv: Vec<[f64; 2]>,
    /// Bucket `b` holds `bucket_rays[bucket_start[b]..bucket_start[b + 1]]`.
    bucket_start: Vec<u32>,
    bucket_rays: Vec<u32>,
    /// Bucket of each ray.
    bucket_of: Vec<u32>,
    stack: Vec<u32>,
}

thread_local! {
    static WORKSPACE: RefCell<Workspace> = RefCell::new(Workspace::default());
}

/// The 2D bucket grid over the origins' rectangle.
struct Grid {
    lo: [f64; 2],
    scale: [f64; 2],
    /// The last bucket coordinate on each axis.
    top: [f64; 2],
}

impl Grid {
    /// Bucket coordinate of `x` on axis `a` (monotone in `x`). Branch-free:
    /// the conversion saturates, below 0 to 0.
    #[inline]
    fn cell(&self, a: usize, x: f64) -> usize {
        let c = (x - self.lo[a]) * self.scale[a];
        (if c < self.top[a] { c } else { self.top[a] }) as u32 as usize
    }
}

/// The reach of a bundle's unbounded sides, in lengths of the longer side
/// of its origins' rectangle (step 0). On the phantom's spatula bundles
/// (`fissure bench rays`, whole lines) twice the longer side was fastest
/// among the shorter side and 1, 2 and 4 times the longer: a longer reach
/// sweeps more triangles, a shorter one leaves more sides to cast again.
const LINE_REACH: f64 = 2.0;

/// What a bundle left to its caller: the reach `R` (m) its unbounded sides
/// were clipped to (module documentation, step 0). A side of a ray must be
/// cast again with its own bound when it looks farther than `R` and the
/// bundle found nothing on it ([`BundleCast::recast_range`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct BundleCast {
    /// The reach unbounded sides were clipped to, m (infinite: none was).
    pub reach: f64,
}

impl BundleCast {
    /// The range a ray of range `range` with the bundle's answer `hits` must
    /// be cast again with: its own bound on each side left to recast, and
    /// "nowhere" (-1) on a side the bundle answered; `None` when no side is
    /// left. The answer of a recast side replaces the bundle's (none).
    #[inline]
    pub fn recast_range(&self, range: &RayRange, hits: &NodeHits) -> Option<RayRange> {
        let front = range.front > self.reach && hits.front.is_none();
        let behind = range.behind > self.reach && hits.behind.is_none();
        (front || behind).then(|| RayRange {
            behind: if behind { range.behind } else { -1.0 },
            front: if front { range.front } else { -1.0 },
        })
    }
}

/// `range` with each side that looks without bound (`+inf`) clipped to
/// `reach`; a side that looks nowhere (negative, `-inf` included, or NaN)
/// stays so.
#[inline]
fn clip_unbounded(range: RayRange, reach: f64) -> RayRange {
    let side = |b: f64| if b == f64::INFINITY { reach } else { b };
    RayRange {
        behind: side(range.behind),
        front: side(range.front),
    }
}

/// Casts the bundle `origins[i] + t dir` within `ranges[i]` (whole lines
/// where `ranges` is shorter) into `out` (defaulted by the caller); the
/// sides [`BundleCast::recast_range`] names are left to the caller.
pub(super) fn cast_bundle(
    bvh: &Bvh,
    origins: &[Point3<f64>],
    dir: Vector3<f64>,
    ranges: &[RayRange],
    out: &mut [NodeHits],
) -> BundleCast {
    if bvh.nodes.is_empty() || (dir.x == 0.0 && dir.y == 0.0 && dir.z == 0.0) {
        // Nothing to hit (an empty tree), or a direction no ray can follow:
        // every answer is empty, whatever the range.
        return BundleCast {
            reach: f64::INFINITY,
        };
    }
    WORKSPACE.with(|ws| cast_in(bvh, origins, dir, ranges, out, &mut ws.borrow_mut()))
}

fn cast_in(
    bvh: &Bvh,
    origins: &[Point3<f64>],
    dir: Vector3<f64>,
    ranges: &[RayRange],
    out: &mut [NodeHits],
    ws: &mut Workspace,
) -> BundleCast {
    let n = origins.len();
    // Two vectors perpendicular to `dir`: `e1` across the smallest component.
    let d = dir / dir.norm();
    let a = d.iamin();
    let e1 = d.cross(&Vector3::ith(a, 1.0)).normalize();
    let e2 = d.cross(&e1);
    let e = [e1, e2];
    // One prepared line for the whole bundle: the permutation and the shear
    // of the watertight test depend on the direction only (step 3).
    let line = WatertightRay::new(origins[0], dir);

    // Projected origins and their rectangle.
    ws.uv.clear();
    let mut rlo = [f64::INFINITY; 2];
    let mut rhi = [f64::NEG_INFINITY; 2];
    for o in origins {
        let uv = [e1.dot(&o.coords), e2.dot(&o.coords)];
        for k in 0..2 {
            rlo[k] = rlo[k].min(uv[k]);
            rhi[k] = rhi[k].max(uv[k]);
        }
        ws.uv.push(uv);
    }
    // The reach of unbounded sides (step 0). Origins on one point give 0 and
    // no finite origin gives -inf: every unbounded side is then cast again
    // alone (`min`/`max` above skip a NaN origin).
    let clip_to = LINE_REACH * (rhi[0] - rlo[0]).max(rhi[1] - rlo[1]);
    let mut any_clipped = false;
    ws.ranges.clear();
    for i in 0..n {
        let r = ranges.get(i).copied().unwrap_or(RayRange::LINE);
        let c = clip_unbounded(r, clip_to);
        any_clipped |= c != r;
        ws.ranges.push(c);
    }
    let cast = BundleCast {
        reach: if any_clipped { clip_to } else { f64::INFINITY },
    };

    // Segment box and reach.
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    // Longest |t| of a segment end; times |dir| below (the reach only sizes
    // the margin).
    let mut reach = 0.0f64;
    for (o, r) in origins.iter().zip(&ws.ranges) {
        if let Some((p, q)) = segment(o, &dir, Some(r)) {
            lo = lo.inf(&p.inf(&q));
            hi = hi.sup(&p.sup(&q));
            reach = reach.max(r.behind).max(r.front);
        }
    }
    let reach = reach * dir.norm() * (1.0 + 1e-9);
    if lo.x > hi.x {
        // No ray looks anywhere within finite bounds: nothing to find here;
        // the caller recasts what needs it.
        return cast;
    }
    let (lo, hi) = crate::collide::rays::widen_box(lo, hi);
    let size = rlo
        .iter()
        .chain(rhi.iter())
        .fold(0.0f64, |m, x| m.max(x.abs()));
    let margin = 1e-9 * (size + reach + (rhi[0] - rlo[0]) + (rhi[1] - rlo[1])) + 1e-12;

    // Bucket grid: about two rays a bucket, cells as square as the rectangle
    // allows.
    let w = [rhi[0] - rlo[0], rhi[1] - rlo[1]];
    let cells = (n / 2).max(1) as f64;
    let nu = if w[0] <= 0.0 {
        1.0
    } else if w[1] <= 0.0 {
        cells
    } else {
        (cells * w[0] / w[1]).sqrt().round().clamp(1.0, cells)
    };
    let nv = (cells / nu).round().max(1.0);
    let grid_n = [nu as usize, nv as usize];
    let grid = Grid {
        lo: rlo,
        scale: [0, 1].map(|k| {
            if w[k] > 0.0 {
                grid_n[k] as f64 / w[k]
            } else {
                0.0
            }
        }),
        top: grid_n.map(|k| (k - 1) as f64),
    };
    let buckets = grid_n[0] * grid_n[1];
    ws.bucket_start.clear();
    ws.bucket_start.resize(buckets + 1, 0);
    ws.bucket_of.clear();
    for uv in &ws.uv {
        let b = grid.cell(1, uv[1]) * grid_n[0] + grid.cell(0, uv[0]);
        ws.bucket_of.push(b as u32);
        ws.bucket_start[b + 1] += 1;
    }
    for b in 0..buckets {
        ws.bucket_start[b + 1] += ws.bucket_start[b];
    }
    ws.bucket_rays.clear();
    ws.bucket_rays.resize(n, 0);
    for (i, &b) in ws.bucket_of.iter().enumerate() {
        let b = b as usize;
        // `bucket_start[b]` runs ahead while filling, then is restored below.
        ws.bucket_rays[ws.bucket_start[b] as usize] = i as u32;
        ws.bucket_start[b] += 1;
    }
    for b in (1..=buckets).rev() {
        ws.bucket_start[b] = ws.bucket_start[b - 1];
    }
    ws.bucket_start[0] = 0;

    // The swept volume: the segment box and the prism over the rectangle.
    // The segment box rounded outwards to `f32`: the node boxes' own
    // precision, so that the box test needs no conversion (a node that meets
    // the `f64` box meets this one).
    let (qlo, qhi) = (lo.coords.map(round_down), hi.coords.map(round_up));
    let ea = [e1.abs(), e2.abs()];
    let enters = |k: usize| {
        let nd = &bvh.nodes[k];
        if !((nd.lo[0] <= qhi[0])
            & (nd.lo[1] <= qhi[1])
            & (nd.lo[2] <= qhi[2])
            & (nd.hi[0] >= qlo[0])
            & (nd.hi[1] >= qlo[1])
            & (nd.hi[2] >= qlo[2]))
        {
            return false;
        }
        let blo = nd.lo.map(f64::from);
        let bhi = nd.hi.map(f64::from);
        let c = [0, 1, 2].map(|a| 0.5 * (blo[a] + bhi[a]));
        let h = [0, 1, 2].map(|a| 0.5 * (bhi[a] - blo[a]));
        (0..2).all(|k| {
            let mid = e[k].x * c[0] + e[k].y * c[1] + e[k].z * c[2];
            let half = (ea[k].x * h[0] + ea[k].y * h[1] + ea[k].z * h[2]) * (1.0 + 1e-12);
            mid - half <= rhi[k] + margin && mid + half >= rlo[k] - margin
        })
    };
    let ranges = &ws.ranges;
    ws.stack.clear();
    if enters(0) {
        ws.stack.push(0);
    }
    while let Some(k) = ws.stack.pop() {
        let nd = &bvh.nodes[k as usize];
        if nd.count == 0 {
            for c in [nd.index, k + 1] {
                if enters(c as usize) {
                    ws.stack.push(c);
                }
            }
            continue;
        }
        let first = nd.index as usize;
        for j in first..first + nd.count as usize {
            let [a, b, c] = &bvh.verts[j];
            let p = [a, b, c].map(|x| [e1.dot(&x.coords), e2.dot(&x.coords)]);
            let mut cell_lo = [0usize; 2];
            let mut cell_hi = [0usize; 2];
            let mut rect = [[0.0f64; 2]; 2];
            let mut m = margin;
            let mut outside = false;
            for k in 0..2 {
                let tlo = lesser(lesser(p[0][k], p[1][k]), p[2][k]);
                let thi = greater(greater(p[0][k], p[1][k]), p[2][k]);
                let mk = margin + 1e-9 * greater(tlo.abs(), thi.abs());
                m = greater(m, mk);
                let (tlo, thi) = (tlo - mk, thi + mk);
                // A triangle with a NaN vertex may pass (the plain
                // comparisons may skip the NaN): the triangle tests reject
                // it (a NaN determinant).
                if !(tlo <= rhi[k] && thi >= rlo[k]) {
                    outside = true;
                    break;
                }
                cell_lo[k] = grid.cell(k, tlo);
                cell_hi[k] = grid.cell(k, thi);
                rect[k] = [tlo, thi];
            }
            if outside {
                continue;
            }
            // Set up for the first ray in the rectangle only.
            let mut edges: Option<Option<[[f64; 3]; 3]>> = None;
            let id = bvh.ids[j];
            // Shared by the rays that pass the edge tests of this triangle.
            let mut degenerate: Option<bool> = None;
            for bv in cell_lo[1]..=cell_hi[1] {
                let row = bv * grid_n[0];
                let from = ws.bucket_start[row + cell_lo[0]] as usize;
                let to = ws.bucket_start[row + cell_hi[0] + 1] as usize;
                for &i in &ws.bucket_rays[from..to] {
                    let i = i as usize;
                    let uv = ws.uv[i];
                    // The origin's own projection must lie in the widened
                    // rectangle too (the bucket only bounds it), and in
                    // the widened triangle.
                    if !(uv[0] >= rect[0][0]
                        && uv[0] <= rect[0][1]
                        && uv[1] >= rect[1][0]
                        && uv[1] <= rect[1][1])
                    {
                        continue;
                    }
                    if let Some(f) = edges.get_or_insert_with(|| edge_filter(&p, m))
                        && !f.iter().all(|g| g[0] * uv[0] + g[1] * uv[1] + g[2] >= 0.0)
                    {
                        continue;
                    }
                    let hit = match bvh.test {
                        RayTest::Watertight => line.intersect_from(&origins[i], a, b, c, || {
                            *degenerate.get_or_insert_with(|| degenerate_or_parallel(&dir, a, b, c))
                        }),
                        RayTest::MollerTrumbore => moller_trumbore(&origins[i], &dir, a, b, c),
                    };
                    if let Some(h) = hit
                        && ranges[i].contains(h.t)
                    {
                        keep_nearest(
                            &mut out[i],
                            Hit {
                                triangle: id,
                                t: h.t,
                                u: h.u,
                                v: h.v,
                            },
                        );
                    }
                }
            }
        }
    }
    cast
}

/// The lesser of `a` and `b` by one comparison (`b` when either is NaN):
/// one instruction where `f64::min` takes four.
#[inline(always)]
fn lesser(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

/// The greater of `a` and `b` by one comparison (`b` when either is NaN).
#[inline(always)]
fn greater(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

/// The edge lines of a triangle projected onto the bundle's plane (`p`, m),
/// each moved outwards by `m` (m): `g[0] u + g[1] v + g[2] >= 0` on all three
/// for every projected origin `(u, v)` within `m` of the closed triangle
/// (step 3). `g[0], g[1]` is the edge's inward normal, as long as the edge;
/// the offset takes `m` times its 1-norm, at least its length. `None`, and
/// the rectangle alone filters, where the projected triangle is thin
/// (twice its area at most `1e-4` of its longest edge squared, a triangle
/// seen edge on included), smaller than `m` or not finite: there the
/// rounding of the normals is not bounded far below `m`.
///
/// Why this is exact: the rounding of the projections is about
/// `1e-16 (|p| + |origin|)`, the normal's error times the distance to a
/// candidate origin (within the rectangle, at most `l + 2 m <= 3 l` away
/// for a longest edge `l >= m`) about `1e-15 |p| l`, while the shortest
/// edge of a triangle that passes the thinness test is above `1e-4 l` and
/// `m >= 1e-9 |p|`, so the offset is above `1e-13 |p| l`: every origin
/// whose line the exact test can find in the triangle passes.
#[inline]
fn edge_filter(p: &[[f64; 2]; 3], m: f64) -> Option<[[f64; 3]; 3]> {
    let edge = |i: usize, j: usize| [p[j][0] - p[i][0], p[j][1] - p[i][1]];
    let (ab, bc, ca) = (edge(0, 1), edge(1, 2), edge(2, 0));
    let area2 = ab[0] * (-ca[1]) - ab[1] * (-ca[0]);
    let len2 = |e: [f64; 2]| e[0] * e[0] + e[1] * e[1];
    let longest2 = len2(ab).max(len2(bc)).max(len2(ca));
    // False for a NaN or infinite area too.
    let fat = area2.abs() > 1e-4 * longest2 && longest2.is_finite() && longest2 > m * m;
    if !fat {
        return None;
    }
    let s = area2.signum();
    let line = |from: [f64; 2], e: [f64; 2]| {
        let (nx, ny) = (-s * e[1], s * e[0]);
        [
            nx,
            ny,
            m * (nx.abs() + ny.abs()) - (nx * from[0] + ny * from[1]),
        ]
    };
    Some([line(p[0], ab), line(p[1], bc), line(p[2], ca)])
}

#[cfg(test)]
mod tests {
    use super::{BUNDLE_MIN, Traversal, edge_filter};
    use crate::collide::rays::brute::cast_line;
    use crate::collide::rays::ray::{RayTest, WatertightRay};
    use crate::collide::{Bvh, NodeHits, RayBackend, RayRange};
    use crate::mesh::blocks;
    use faer::Par;
    use nalgebra::{Point3, Vector3};

    /// The boundary of a 30 mm cube of 6 cells a side, deformed by `f`,
    /// with `extra` triangles appended.
    fn surface(
        f: impl Fn(&mut Point3<f64>),
        extra: &[[Point3<f64>; 3]],
    ) -> (Vec<[u32; 3]>, Vec<Point3<f64>>) {
        let mesh = blocks::cube(0.03, 6);
        let s = mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&mesh.nodes, &mut pos);
        pos.iter_mut().for_each(f);
        let mut tris = s.triangles;
        for t in extra {
            let k = pos.len() as u32;
            pos.extend_from_slice(t);
            tris.push([k, k + 1, k + 2]);
        }
        (tris, pos)
    }

    /// Bundled, per ray (parallel and in sequence) and the brute force's
    /// whole-line answers clipped to the ranges, bit for bit; returns how
    /// many sides hit.
    fn check(
        tris: &[[u32; 3]],
        pos: &[Point3<f64>],
        test: RayTest,
        o: &[Point3<f64>],
        d: &[Vector3<f64>],
        r: &[RayRange],
        what: &str,
    ) -> usize {
        let want: Vec<NodeHits> = o
            .iter()
            .zip(d)
            .zip(r)
            .map(|((o, d), r)| r.clip(cast_line(tris, pos, test, *o, *d)))
            .collect();
        let mut bvh = Bvh::with_test(tris, pos, test).unwrap();
        for t in [Traversal::Bundled, Traversal::PerRay] {
            bvh.set_traversal(t);
            let mut got = Vec::new();
            bvh.cast_ranged(o, d, r, &mut got);
            assert_eq!(got, want, "{t:?} {test:?} {what}");
            bvh.cast_ranged_with(o, d, r, Par::Seq, &mut got);
            assert_eq!(got, want, "seq {t:?} {test:?} {what}");
        }
        want.iter()
            .map(|h| usize::from(h.behind.is_some()) + usize::from(h.front.is_some()))
            .sum()
    }

    /// `nx x ny` origins at height `z`, `spacing` apart, shifted by `offset`
    /// (fractions of the spacing) from `corner`.
    fn grid(
        corner: [f64; 2],
        spacing: f64,
        offset: [f64; 2],
        (nx, ny): (usize, usize),
        z: f64,
    ) -> Vec<Point3<f64>> {
        let mut o = Vec::new();
        for i in 0..nx {
            for j in 0..ny {
                o.push(Point3::new(
                    corner[0] + (i as f64 + offset[0]) * spacing,
                    corner[1] + (j as f64 + offset[1]) * spacing,
                    z,
                ));
            }
        }
        o
    }

    /// Lattice-aligned grids (every line through vertices or edges of the
    /// cube's faces: half the cell size apart from a vertex), offset grids,
    /// rays that hit nothing, bundles of exactly [`BUNDLE_MIN`] rays and
    /// longer, bounded, one-sided and whole lines, both ray tests.
    #[test]
    fn bundles_equal_brute_force_through_vertices_edges_and_misses() {
        let h = 0.03 / 6.0;
        for amp in [0.0, 0.2e-3] {
            let (tris, pos) = surface(
                |p| {
                    p.x += amp * (90.0 * p.y).sin();
                    p.z += amp * (80.0 * p.x).sin();
                },
                &[],
            );
            for (corner, offset, n, dir) in [
                // Through vertices and edge midpoints of the lattice.
                ([0.0, 0.0], [0.0, 0.0], (13, 13), Vector3::z()),
                ([0.0, 0.0], [0.0, 0.0], (8, 8), -Vector3::z()),
                // Through the diagonals of the faces' cells.
                ([0.0, 0.0], [0.25, 0.25], (12, 11), Vector3::z()),
                ([0.0, 0.0], [0.372, 0.618], (9, 8), Vector3::z()),
                (
                    [0.0, 0.0],
                    [0.372, 0.618],
                    (10, 10),
                    Vector3::new(0.1, -0.2, 1.0),
                ),
                (
                    [0.0, 0.0],
                    [0.0, 0.0],
                    (10, 10),
                    Vector3::new(1.0, 1.0, 1.0),
                ),
                // Half the grid beside the cube: lines that hit nothing.
                ([0.02, 0.02], [0.5, 0.5], (10, 10), Vector3::z()),
                ([0.05, 0.05], [0.5, 0.5], (8, 8), Vector3::z()),
            ] {
                let o = grid(corner, h / 2.0, offset, n, 0.015);
                let d = vec![dir.normalize(); o.len()];
                assert!(o.len() >= BUNDLE_MIN);
                for test in [RayTest::Watertight, RayTest::MollerTrumbore] {
                    let bounded: Vec<RayRange> = (0..o.len())
                        .map(|i| RayRange {
                            behind: 0.02 * (i % 3) as f64 / 2.0,
                            front: 0.02 - 0.005 * (i % 4) as f64,
                        })
                        .collect();
                    let whole = vec![RayRange::LINE; o.len()];
                    let one_sided: Vec<RayRange> = (0..o.len())
                        .map(|i| RayRange {
                            behind: if i % 2 == 0 { f64::INFINITY } else { -1.0 },
                            front: if i % 2 == 0 { 0.004 } else { f64::INFINITY },
                        })
                        .collect();
                    for (r, kind) in [(bounded, "bounded"), (whole, "whole"), (one_sided, "one")] {
                        let what = format!("amp {amp} {corner:?} {offset:?} {n:?} {dir:?} {kind}");
                        let sides = check(&tris, &pos, test, &o, &d, &r, &what);
                        if corner[0] > 0.04 {
                            assert_eq!(sides, 0, "{what}");
                        } else {
                            assert!(sides > 0, "{what}");
                        }
                    }
                }
            }
        }
    }

    /// Degenerate triangles (a repeated vertex, collinear vertices, all
    /// three equal) and a triangle parallel to the rays, placed across the
    /// bundle's lines, hit nothing; the rest of the surface is found as the
    /// brute force finds it.
    #[test]
    fn degenerate_and_parallel_triangles_in_a_bundle() {
        let p = |x: f64, y: f64, z: f64| Point3::new(x, y, z);
        let extra = [
            [p(0.0, 0.01, 0.02), p(0.03, 0.01, 0.02), p(0.03, 0.01, 0.02)],
            [
                p(0.0, 0.0, 0.021),
                p(0.015, 0.015, 0.021),
                p(0.03, 0.03, 0.021),
            ],
            [p(0.01, 0.01, 0.022); 3],
            // In the plane y = 0.0125, containing the direction z.
            [
                p(0.0, 0.0125, 0.0),
                p(0.03, 0.0125, 0.0),
                p(0.015, 0.0125, 0.03),
            ],
        ];
        let (tris, pos) = surface(|_| {}, &extra);
        let h = 0.03 / 6.0;
        let o = grid([0.0, 0.0], h / 2.0, [0.0, 0.0], (13, 13), 0.025);
        let d = vec![-Vector3::z(); o.len()];
        let r = vec![
            RayRange {
                behind: 0.01,
                front: 0.03,
            };
            o.len()
        ];
        for test in [RayTest::Watertight, RayTest::MollerTrumbore] {
            assert!(check(&tris, &pos, test, &o, &d, &r, "degenerate") > 0);
        }
    }

    /// The edge filter keeps every origin whose line the watertight test
    /// finds in the triangle (random triangles, lines aimed at their edges
    /// and vertices), and stands aside for thin projections.
    #[test]
    fn edge_filter_keeps_every_hit() {
        let mut rnd = crate::test_rng::unit(7);
        let dir = Vector3::new(0.3, -0.2, 1.0).normalize();
        let a = dir.iamin();
        let e1 = dir.cross(&Vector3::ith(a, 1.0)).normalize();
        let e2 = dir.cross(&e1);
        let mut tested = 0;
        for _ in 0..2000 {
            let v: [Point3<f64>; 3] =
                std::array::from_fn(|_| Point3::new(rnd() * 0.01, rnd() * 0.01, rnd() * 0.01));
            let p = v.map(|x| [e1.dot(&x.coords), e2.dot(&x.coords)]);
            let m = 1e-9 * 0.02 + 1e-12;
            let Some(f) = edge_filter(&p, m) else {
                continue;
            };
            for _ in 0..20 {
                // A point of an edge (often exactly a vertex), or inside.
                let (i, j) = ((rnd() * 3.0) as usize, (rnd() * 3.0) as usize);
                let s = if rnd() < 0.3 { 0.0 } else { rnd() };
                let target = v[i] + (v[j] - v[i]) * s;
                let o = target - dir * (0.02 * rnd() - 0.01);
                let ray = WatertightRay::new(o, dir);
                if ray.intersect(&v[0], &v[1], &v[2]).is_some() {
                    tested += 1;
                    let uv = [e1.dot(&o.coords), e2.dot(&o.coords)];
                    assert!(
                        f.iter().all(|g| g[0] * uv[0] + g[1] * uv[1] + g[2] >= 0.0),
                        "{v:?} {o}"
                    );
                }
            }
        }
        assert!(tested > 1000, "{tested}");
        // A triangle seen edge on: no filter.
        let thin = [[0.0, 0.0], [1.0, 0.0], [0.5, 1e-6]];
        assert!(edge_filter(&thin, 1e-12).is_none());
    }
}
