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
//! reach): the last point still between the walls.
//!
//! Written here, not taken from a crate: the test is the project's own ray
//! cast on its own surface, and the rest is an eigen-decomposition
//! (nalgebra).

use super::TetMesh;
use super::phantom::FissureLandmark;
use crate::collide::ray::moller_trumbore;
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

    /// The nearest hit in front of `o` along the unit `d` within `reach`
    /// (its distance, and whether the wall there faces along `d`: is left
    /// from inside), and the number of crossings of the whole half-line
    /// (for parity).
    fn cast(&self, o: &Point3<f64>, d: &Vector3<f64>, reach: f64) -> (Option<(f64, bool)>, usize) {
        let mut best: Option<(f64, bool)> = None;
        let mut crossings = 0;
        for [a, b, c] in &self.tris {
            if let Some(h) = moller_trumbore(o, d, a, b, c)
                && h.t > 0.0
            {
                crossings += 1;
                if h.t <= reach && best.is_none_or(|(t, _)| h.t < t) {
                    best = Some((h.t, (b - a).cross(&(c - a)).dot(d) > 0.0));
                }
            }
        }
        (best, crossings)
    }

    /// The distance to the nearest wall in front of `o` along `d` within
    /// `reach`.
    fn hit(&self, o: &Point3<f64>, d: &Vector3<f64>, reach: f64) -> Option<f64> {
        self.cast(o, d, reach).0.map(|(t, _)| t)
    }
}

/// Point queries against the boundary near a fissure: whether a point is
/// in the tissue, for checking where a plate fits.
pub struct Probe {
    walls: Walls,
    reach_m: f64,
}

impl Probe {
    /// The boundary within `reach_m` of `centre` (queries are exact for
    /// points whose rays leave that ball only through it).
    pub fn new(mesh: &TetMesh, centre: Point3<f64>, reach_m: f64) -> Self {
        Self {
            walls: Walls::near(mesh, &centre, reach_m),
            reach_m,
        }
    }

    /// Whether `p` is inside the tissue: along each of three rays the
    /// nearest wall within the reach is met from inside (its outward normal
    /// along the ray), by a majority (robust to a ray through an edge). A
    /// point with no wall within the reach along a ray counts as outside
    /// there.
    pub fn inside(&self, p: &Point3<f64>) -> bool {
        let dirs = [
            Vector3::new(0.267, 0.535, 0.802),
            Vector3::new(-0.802, 0.267, -0.535),
            Vector3::new(0.535, -0.802, -0.267),
        ];
        dirs.iter()
            .filter(|d| {
                self.walls
                    .cast(p, &d.normalize(), self.reach_m)
                    .0
                    .is_some_and(|(_, from_inside)| from_inside)
            })
            .count()
            >= 2
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
        hit_t.push(t.map(|(t, _)| t));
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
    let depth = (p - entry).dot(&direction).max(0.0);
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
        assert!((l.depth - 0.03).abs() < 0.003, "depth {}", l.depth);
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
