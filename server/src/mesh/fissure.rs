//! Finding a fissure of a meshed brain near a point the user gives: its
//! mid-plane, its depth direction and its entry on the outer surface, as a
//! [`FissureLandmark`] (the phantom's own fissures are known by
//! construction; a patient's mesh needs them found). Metres throughout.
//!
//! # Method
//! The point `p` must lie in the fissure's gap, outside the tissue (the
//! cerebrospinal fluid between the walls). From `p`, `N` rays on a
//! Fibonacci sphere are cast against the boundary surface (Möller-Trumbore,
//! hits within the reach `R` only). In a fissure the gap is a thin sheet:
//! rays across it hit a wall after about half the gap, rays along it run
//! far. So the mid-plane's normal is the leading eigenvector of the
//! *closeness tensor* `M = sum_i d_i d_i^T / t_i^2` over the rays that hit
//! (direction `d_i`, hit distance `t_i`), and the *sheetness* is the ratio of
//! its two largest eigenvalues (1 for a round cavity, large for a sheet); a
//! point whose ratio is below [`FissureOptions::min_sheetness`] is refused.
//! The gap (the landmark's width) is `t(n) + t(-n)`.
//!
//! The depth direction points from the outside in: the mean of the in-plane
//! rays (`|d . n| < 0.3`) that leave the reach without a hit is the way
//! out, and the depth direction is its opposite, projected into the plane
//! (failing any escape, the in-plane ray with the longest hit). The entry is
//! found by walking from `p` outwards in steps of `R / 40` until the walls
//! are gone (both rays along `+-n` run further than four gaps, or leave the
//! reach): the last point still between the walls. The depth runs from the
//! entry to the floor: where the way in from `p` meets tissue.
//!
//! Written here, not taken from a crate: the test is the project's own ray
//! cast on its own surface, and the rest is an eigen-decomposition
//! (nalgebra).

use super::TetMesh;
use super::phantom::FissureLandmark;
use crate::collide::rays::ray::moller_trumbore;
use nalgebra::{Matrix3, Point3, SymmetricEigen, Unit, Vector3};

/// How the fissure is searched for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FissureOptions {
    /// Rays further than this from the point count as escaping, m.
    pub reach_m: f64,
    /// Number of rays cast from the point.
    pub rays: usize,
    /// Smallest ratio of the closeness tensor's two largest eigenvalues
    /// accepted as a sheet-like gap.
    pub min_sheetness: f64,
}

impl Default for FissureOptions {
    fn default() -> Self {
        Self {
            reach_m: 0.04,
            rays: 1024,
            min_sheetness: 2.0,
        }
    }
}

/// A fissure found near a point, with what the search measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoundFissure {
    /// The fissure as the placement code uses it
    /// ([`crate::collide::FissurePlacement`]).
    pub landmark: FissureLandmark,
    /// The point given, m.
    pub point_m: Point3<f64>,
    /// Ratio of the closeness tensor's two largest eigenvalues (module doc).
    pub sheetness: f64,
    /// Rays that hit a wall within the reach, of those cast.
    pub hits: usize,
}

/// Why no fissure was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FissureError {
    /// The point is inside the tissue.
    #[error(
        "the point ({:.1}, {:.1}, {:.1}) mm is inside the tissue (the nearest wall is {:.1} mm away); give a point in the fissure's gap",
        .point_m[0] * 1e3, .point_m[1] * 1e3, .point_m[2] * 1e3, .wall_m * 1e3
    )]
    Inside { point_m: [f64; 3], wall_m: f64 },
    /// Too few rays hit the tissue: the point is not near the brain.
    #[error(
        "only {hits} of {rays} rays from ({:.1}, {:.1}, {:.1}) mm meet the tissue within {:.0} mm: the point is not in a fissure",
        .point_m[0] * 1e3, .point_m[1] * 1e3, .point_m[2] * 1e3, .reach_m * 1e3
    )]
    Open {
        point_m: [f64; 3],
        hits: usize,
        rays: usize,
        reach_m: f64,
    },
    /// The gap about the point is not a sheet.
    #[error(
        "the gap about ({:.1}, {:.1}, {:.1}) mm is not sheet-like (eigenvalue ratio {sheetness:.2}, at least {min:.2} wanted): not a fissure",
        .point_m[0] * 1e3, .point_m[1] * 1e3, .point_m[2] * 1e3
    )]
    NotASheet {
        point_m: [f64; 3],
        sheetness: f64,
        min: f64,
    },
}

/// The boundary triangles of a mesh as corner positions, with the
/// distance-culled subset a point's rays can reach.
struct Walls {
    tris: Vec<[Point3<f64>; 3]>,
}

impl Walls {
    fn near(mesh: &TetMesh, p: &Point3<f64>, reach_m: f64) -> Self {
        let b = mesh.boundary();
        let tris = b
            .triangles
            .iter()
            .map(|t| t.map(|v| mesh.nodes[b.to_volume[v as usize] as usize]))
            .filter(|c| {
                // Bounding sphere about the centroid.
                let m = Point3::from((c[0].coords + c[1].coords + c[2].coords) / 3.0);
                let r = c.iter().map(|q| (q - m).norm()).fold(0.0, f64::max);
                (m - p).norm() <= reach_m + r
            })
            .collect();
        Self { tris }
    }

    /// The distance of the nearest hit in front of `o` along the unit `d`
    /// within `reach`, and the number of crossings of the whole half-line
    /// (for parity).
    fn cast(&self, o: &Point3<f64>, d: &Vector3<f64>, reach: f64) -> (Option<f64>, usize) {
        let mut best: Option<f64> = None;
        let mut crossings = 0;
        for [a, b, c] in &self.tris {
            if let Some(h) = moller_trumbore(o, d, a, b, c)
                && h.t > 0.0
            {
                crossings += 1;
                if h.t <= reach && best.is_none_or(|t| h.t < t) {
                    best = Some(h.t);
                }
            }
        }
        (best, crossings)
    }

    /// The distance to the nearest wall in front of `o` along `d` within
    /// `reach`.
    fn hit(&self, o: &Point3<f64>, d: &Vector3<f64>, reach: f64) -> Option<f64> {
        self.cast(o, d, reach).0
    }
}

/// Point queries near a fissure: whether a point is in the tissue, for
/// checking where a plate fits. Exact point location: the tetrahedra within
/// the reach are bucketed on a grid of cells (2 mm, or a tenth of the reach
/// if smaller), each with its barycentric map; a point is in the tissue when
/// a tetrahedron of its cell holds it (barycentric coordinates within
/// `-1e-12`). Points beyond the reach count as outside. A placement search
/// asks millions of these; three ray casts against the walls each, as
/// before, took seconds per thousand placements.
pub struct Probe {
    lo: Point3<f64>,
    cell_m: f64,
    dims: [usize; 3],
    /// `starts[c]..starts[c + 1]` index `items` for cell `c`.
    starts: Vec<u32>,
    items: Vec<u32>,
    /// Per tetrahedron: its first node and the inverse of its edge matrix.
    maps: Vec<(Point3<f64>, Matrix3<f64>)>,
}

impl Probe {
    /// The tetrahedra within `reach_m` of `centre` (a tetrahedron is kept
    /// when its bounding box comes within the reach).
    pub fn new(mesh: &TetMesh, centre: Point3<f64>, reach_m: f64) -> Self {
        let cell_m = (0.1 * reach_m).clamp(1e-6, 0.002);
        let lo = centre - Vector3::repeat(reach_m);
        let n = ((2.0 * reach_m / cell_m).ceil() as usize).max(1);
        let dims = [n; 3];
        let mut maps = Vec::new();
        let mut ranges = Vec::new();
        let cell_of = |x: f64, k: usize| -> usize {
            (((x - lo[k]) / cell_m).floor().max(0.0) as usize).min(dims[k] - 1)
        };
        for t in &mesh.tets {
            let p = t.map(|i| mesh.nodes[i as usize]);
            let (mut a, mut b) = (p[0], p[0]);
            for q in &p[1..] {
                a = a.inf(q);
                b = b.sup(q);
            }
            if (0..3).any(|k| b[k] < lo[k] || a[k] > lo[k] + 2.0 * reach_m) {
                continue;
            }
            let e = Matrix3::from_columns(&[p[1] - p[0], p[2] - p[0], p[3] - p[0]]);
            let Some(inv) = e.try_inverse() else { continue };
            let r: [[usize; 2]; 3] = std::array::from_fn(|k| [cell_of(a[k], k), cell_of(b[k], k)]);
            maps.push((p[0], inv));
            ranges.push(r);
        }
        let index = |i: usize, j: usize, k: usize| (i * dims[1] + j) * dims[2] + k;
        let mut counts = vec![0u32; dims[0] * dims[1] * dims[2] + 1];
        let each = |r: &[[usize; 2]; 3], f: &mut dyn FnMut(usize)| {
            for i in r[0][0]..=r[0][1] {
                for j in r[1][0]..=r[1][1] {
                    for k in r[2][0]..=r[2][1] {
                        f(index(i, j, k));
                    }
                }
            }
        };
        for r in &ranges {
            each(r, &mut |c| counts[c + 1] += 1);
        }
        for c in 1..counts.len() {
            counts[c] += counts[c - 1];
        }
        let mut fill = counts.clone();
        let mut items = vec![0u32; *counts.last().unwrap_or(&0) as usize];
        for (t, r) in ranges.iter().enumerate() {
            each(r, &mut |c| {
                items[fill[c] as usize] = t as u32;
                fill[c] += 1;
            });
        }
        Self {
            lo,
            cell_m,
            dims,
            starts: counts,
            items,
            maps,
        }
    }

    /// Whether `p` is inside the tissue (type doc).
    pub fn inside(&self, p: &Point3<f64>) -> bool {
        let mut c = [0usize; 3];
        for k in 0..3 {
            let x = ((p[k] - self.lo[k]) / self.cell_m).floor();
            if !(x >= 0.0 && x < self.dims[k] as f64) {
                return false;
            }
            c[k] = x as usize;
        }
        let cell = (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2];
        let range = self.starts[cell] as usize..self.starts[cell + 1] as usize;
        self.items[range].iter().any(|&t| {
            let (o, inv) = &self.maps[t as usize];
            let b = inv * (p - o);
            const EPS: f64 = -1e-12;
            b.x >= EPS && b.y >= EPS && b.z >= EPS && 1.0 - b.x - b.y - b.z >= EPS
        })
    }
}

/// `n` unit directions spread evenly over the sphere (Fibonacci lattice).
fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f64;
            Vector3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// Finds the fissure whose gap holds `p` (module doc).
pub fn locate(
    mesh: &TetMesh,
    p: Point3<f64>,
    opts: &FissureOptions,
) -> Result<FoundFissure, FissureError> {
    let reach = opts.reach_m;
    let at = [p.x, p.y, p.z];
    // Walls within the reach of every point the entry walk visits.
    let walls = Walls::near(mesh, &p, 3.0 * reach);
    let dirs = fibonacci_sphere(opts.rays.max(64));
    let mut hit_t = Vec::with_capacity(dirs.len());
    let mut odd = 0usize;
    for d in &dirs {
        let (t, crossings) = walls.cast(&p, d, reach);
        odd += crossings % 2;
        hit_t.push(t);
    }
    let nearest = hit_t
        .iter()
        .flatten()
        .copied()
        .fold(f64::INFINITY, f64::min);
    // Inside a closed surface every half-line crosses it an odd number of
    // times; a majority vote is robust to rays through edges.
    if 2 * odd > dirs.len() {
        return Err(FissureError::Inside {
            point_m: at,
            wall_m: nearest,
        });
    }
    let hits = hit_t.iter().filter(|t| t.is_some()).count();
    if hits < dirs.len() / 10 {
        return Err(FissureError::Open {
            point_m: at,
            hits,
            rays: dirs.len(),
            reach_m: reach,
        });
    }
    let mut m = Matrix3::zeros();
    for (d, t) in dirs.iter().zip(&hit_t) {
        if let Some(t) = t {
            let t = t.max(1e-6 * reach);
            m += d * d.transpose() / (t * t);
        }
    }
    let eig = SymmetricEigen::new(m);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (l0, l1) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
    let sheetness = if l1 > 0.0 { l0 / l1 } else { f64::INFINITY };
    if sheetness < opts.min_sheetness {
        return Err(FissureError::NotASheet {
            point_m: at,
            sheetness,
            min: opts.min_sheetness,
        });
    }
    let n = Unit::new_normalize(eig.eigenvectors.column(order[0]).into_owned());
    // The way out: in-plane rays that escape.
    let in_plane = |d: &Vector3<f64>| d.dot(&n).abs() < 0.3;
    let mut out = Vector3::zeros();
    for (d, t) in dirs.iter().zip(&hit_t) {
        if t.is_none() && in_plane(d) {
            out += d;
        }
    }
    if out.norm() < 1e-9 {
        // No in-plane ray escapes: the longest in-plane hit.
        out = dirs
            .iter()
            .zip(&hit_t)
            .filter(|(d, _)| in_plane(d))
            .max_by(|a, b| {
                a.1.unwrap_or(f64::INFINITY)
                    .total_cmp(&b.1.unwrap_or(f64::INFINITY))
            })
            .map(|(d, _)| *d)
            .unwrap_or_else(|| n.cross(&Vector3::x()).normalize());
    }
    let out = Unit::new_normalize(out - n.into_inner() * out.dot(&n));
    let gap_at = |q: &Point3<f64>| -> Option<f64> {
        Some(walls.hit(q, &n, reach)? + walls.hit(q, &(-n.into_inner()), reach)?)
    };
    let width = gap_at(&p).unwrap_or(2.0 * nearest);
    // Walk out until the walls are gone.
    let step = reach / 40.0;
    let mut entry = p;
    for k in 1..=120 {
        let q = p + out.into_inner() * (k as f64 * step);
        match gap_at(&q) {
            Some(g) if g <= 4.0 * width.max(step) => entry = q,
            _ => break,
        }
    }
    // Centre the entry between the walls.
    let a = walls.hit(&entry, &n, reach);
    let b = walls.hit(&entry, &(-n.into_inner()), reach);
    if let (Some(a), Some(b)) = (a, b) {
        entry += n.into_inner() * (0.5 * (a - b));
    }
    let direction = Unit::new_unchecked(-out.into_inner());
    // To the floor: where the way in from the point meets tissue.
    let floor = walls.hit(&p, &direction, reach).unwrap_or(0.0);
    let depth = (p - entry).dot(&direction).max(0.0) + floor;
    Ok(FoundFissure {
        landmark: FissureLandmark {
            entry,
            direction,
            normal: n,
            depth,
            width,
        },
        point_m: p,
        sheetness,
        hits,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::sdf::{Aabb, Sdf};
    use crate::mesh::stuffing::{Lattice, stuff_uniform};

    /// A 60 mm box with a slot of `gap` m cut from its top face down to
    /// 10 mm above its bottom, the slot's mid-plane `x = 0`.
    struct SlottedBox {
        gap: f64,
    }

    const BOX: Aabb = Aabb {
        lo: Point3::new(-0.03, -0.03, -0.03),
        hi: Point3::new(0.03, 0.03, 0.03),
    };

    impl Sdf for SlottedBox {
        fn distance(&self, p: &Point3<f64>) -> f64 {
            // The slot: |x| < gap/2, z > -0.02 (open at the top z = 0.03).
            let slot = (p.x.abs() - 0.5 * self.gap).max(-0.02 - p.z);
            BOX.distance(p).max(-slot)
        }
    }

    fn slotted(gap: f64) -> TetMesh {
        let s = SlottedBox { gap };
        // The slot's walls on lattice planes (x = +-gap/2 = k h/2).
        stuff_uniform(
            &s,
            &Lattice {
                spacing: 0.002,
                levels: 0,
                anchor: Point3::new(0.0, 0.0, 0.0),
                bounds: BOX,
            },
        )
        .unwrap()
    }

    #[test]
    fn a_slot_is_found_with_its_plane_depth_direction_and_entry() {
        let mesh = slotted(0.004);
        let f = locate(
            &mesh,
            Point3::new(0.0, 0.0, 0.0),
            &FissureOptions::default(),
        )
        .unwrap();
        let l = f.landmark;
        // The mid-plane's normal is +-x, within 5 degrees.
        assert!(l.normal.x.abs() > 5f64.to_radians().cos(), "{:?}", l.normal);
        // The way in is -z (the slot opens at the top).
        assert!(
            l.direction.z < -5f64.to_radians().cos(),
            "{:?}",
            l.direction
        );
        // The gap is the slot's 4 mm within a lattice spacing.
        assert!((l.width - 0.004).abs() < 0.002, "width {}", l.width);
        // The entry is at the top face, within two walk steps.
        assert!((l.entry.z - 0.03).abs() < 0.003, "entry {:?}", l.entry);
        assert!(l.entry.x.abs() < 0.001, "entry {:?}", l.entry);
        // The depth reaches the slot's floor, 20 mm below the point.
        assert!((l.depth - 0.05).abs() < 0.003, "depth {}", l.depth);
        assert!(f.sheetness > 2.0);
    }

    #[test]
    fn the_probe_tells_tissue_from_gap() {
        let mesh = slotted(0.004);
        let probe = Probe::new(&mesh, Point3::origin(), 0.1);
        assert!(!probe.inside(&Point3::new(0.0, 0.0, 0.0)));
        assert!(!probe.inside(&Point3::new(0.0, 0.01, 0.02)));
        assert!(probe.inside(&Point3::new(0.01, 0.0, 0.0)));
        assert!(probe.inside(&Point3::new(0.0, 0.0, -0.025)));
        assert!(!probe.inside(&Point3::new(0.0, 0.0, 0.05)));
    }

    #[test]
    fn the_probe_agrees_with_ray_parity_everywhere_in_reach() {
        // Point location on the tetrahedra against the independent test:
        // inside a closed surface a half-line crosses it an odd number of
        // times (three rays, a majority).
        use rand_chacha::rand_core::{RngCore, SeedableRng};
        let mesh = slotted(0.004);
        let probe = Probe::new(&mesh, Point3::origin(), 0.05);
        let walls = Walls::near(&mesh, &Point3::origin(), 1.0);
        let dirs = [
            Vector3::new(0.31, 0.52, 0.79).normalize(),
            Vector3::new(-0.77, 0.29, -0.56).normalize(),
            Vector3::new(0.55, -0.81, -0.21).normalize(),
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut coord = || ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.07;
        let (mut inside, mut n) = (0, 0);
        for _ in 0..3000 {
            let p = Point3::new(coord(), coord(), coord());
            let odd = dirs
                .iter()
                .filter(|d| walls.cast(&p, d, 1.0).1 % 2 == 1)
                .count();
            assert_eq!(probe.inside(&p), odd >= 2, "{p:?}");
            inside += usize::from(odd >= 2);
            n += 1;
        }
        // Both answers were exercised.
        assert!(inside > n / 4 && inside < n, "{inside} of {n}");
        // Beyond the reach every point is outside.
        assert!(!probe.inside(&Point3::new(0.0, 0.0, -0.06)));
    }

    #[test]
    fn points_in_the_tissue_or_far_away_are_refused() {
        let mesh = slotted(0.004);
        let e = locate(
            &mesh,
            Point3::new(0.015, 0.0, 0.0),
            &FissureOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(e, FissureError::Inside { .. }), "{e}");
        assert!(e.to_string().contains("inside the tissue"), "{e}");
        let e = locate(
            &mesh,
            Point3::new(0.0, 0.0, 0.2),
            &FissureOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(e, FissureError::Open { .. }), "{e}");
    }
}
