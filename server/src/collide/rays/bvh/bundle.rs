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
//!    [`super::Entry`] box) and its projection onto `e1`, `e2` meets the
//!    origins' rectangle, i.e. the prism of the rectangle swept along `d` over
//!    the reach.
//! 3. Each triangle of a reached leaf is projected the same way; only the rays
//!    of the buckets its projected rectangle (widened far above rounding)
//!    overlaps, and among them only those whose own projected origin lies in
//!    that rectangle (four comparisons, far cheaper than the triangle test),
//!    are tested, with the same [`PreparedRay`] test on the same `f64`
//!    positions as [`Bvh::cast_one`], and each hit within the ray's range is
//!    folded with [`keep_nearest`].
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

use super::{Bvh, segment};
use crate::collide::rays::brute::keep_nearest;
use crate::collide::rays::ray::PreparedRay;
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
    rays: Vec<PreparedRay>,
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
    n: [usize; 2],
}

impl Grid {
    /// Bucket coordinate of `x` on axis `a` (monotone in `x`).
    #[inline]
    fn cell(&self, a: usize, x: f64) -> usize {
        let c = (x - self.lo[a]) * self.scale[a];
        if c >= 0.0 {
            (c as usize).min(self.n[a] - 1)
        } else {
            0
        }
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

    // Projected origins and their rectangle.
    ws.rays.clear();
    ws.uv.clear();
    let mut rlo = [f64::INFINITY; 2];
    let mut rhi = [f64::NEG_INFINITY; 2];
    for o in origins {
        ws.rays.push(PreparedRay::new(bvh.test, *o, dir));
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
    let mut reach = 0.0f64;
    for (o, r) in origins.iter().zip(&ws.ranges) {
        if let Some((p, q)) = segment(o, &dir, Some(r)) {
            lo = lo.inf(&p.inf(&q));
            hi = hi.sup(&p.sup(&q));
            reach = reach.max((p - o).norm()).max((q - o).norm());
        }
    }
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
        n: grid_n,
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
    let enters = |k: usize| {
        let nd = &bvh.nodes[k];
        let blo = nd.lo.map(f64::from);
        let bhi = nd.hi.map(f64::from);
        if !(0..3).all(|a| blo[a] <= hi[a] && bhi[a] >= lo[a]) {
            return false;
        }
        let c = Vector3::from([0, 1, 2].map(|a| 0.5 * (blo[a] + bhi[a])));
        let h = Vector3::from([0, 1, 2].map(|a| 0.5 * (bhi[a] - blo[a])));
        (0..2).all(|k| {
            let mid = e[k].dot(&c);
            let half = e[k].abs().dot(&h) * (1.0 + 1e-12);
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
            let mut cell_lo = [0usize; 2];
            let mut cell_hi = [0usize; 2];
            let mut rect = [[0.0f64; 2]; 2];
            let mut outside = false;
            for k in 0..2 {
                let (pa, pb, pc) = (
                    e[k].dot(&a.coords),
                    e[k].dot(&b.coords),
                    e[k].dot(&c.coords),
                );
                let tlo = pa.min(pb).min(pc);
                let thi = pa.max(pb).max(pc);
                let m = margin + 1e-9 * tlo.abs().max(thi.abs());
                let (tlo, thi) = (tlo - m, thi + m);
                // Also skips a triangle with a NaN vertex (it meets no line).
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
            let id = bvh.ids[j];
            for bv in cell_lo[1]..=cell_hi[1] {
                let row = bv * grid_n[0];
                let from = ws.bucket_start[row + cell_lo[0]] as usize;
                let to = ws.bucket_start[row + cell_hi[0] + 1] as usize;
                for &i in &ws.bucket_rays[from..to] {
                    let i = i as usize;
                    let uv = ws.uv[i];
                    // The origin's own projection must lie in the widened
                    // rectangle too (the bucket only bounds it).
                    if !(uv[0] >= rect[0][0]
                        && uv[0] <= rect[0][1]
                        && uv[1] >= rect[1][0]
                        && uv[1] <= rect[1][1])
                    {
                        continue;
                    }
                    if let Some(h) = ws.rays[i].intersect(a, b, c)
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
