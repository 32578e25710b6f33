//! Element quality of tetrahedra: volume, radius ratio and dihedral angles,
//! and a histogram helper for summaries.
//!
//! For a tetrahedron with vertices `a, b, c, d`, edges `u = b - a`,
//! `v = c - a`, `w = d - a`:
//! * volume `V = u x v . w / 6` (m^3, signed: positive when well oriented);
//! * inradius `r = 3 |V| / (A_0 + A_1 + A_2 + A_3)` with `A_i` the face areas;
//! * circumradius `R = | |u|^2 (v x w) + |v|^2 (w x u) + |w|^2 (u x v) | / (12 |V|)`;
//! * radius ratio `rho = 3 r / R`, which is 1 for the regular tetrahedron and
//!   tends to 0 for slivers, needles and caps (0 for a flat one);
//! * dihedral angle at the edge shared by faces `i` and `j` (unit outward
//!   normals `n_i`, `n_j`): `theta = pi - acos(n_i . n_j)`. The regular
//!   tetrahedron has all six equal to `acos(1/3) = 70.53` degrees.
//!
//! A degenerate tetrahedron (a face of zero area) reports radius ratio 0 and
//! dihedral angles from the faces that still have a normal (0 or 180 degrees
//! where the tetrahedron is flat); nothing is NaN.

use super::TetMesh;
use nalgebra::{Point3, Vector3};

/// Quality measures of one tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetQuality {
    /// Signed volume, m^3 (negative when inverted).
    pub volume: f64,
    /// `3 r / R` (inradius over circumradius, scaled so the regular tet is 1).
    pub radius_ratio: f64,
    /// Smallest of the six interior dihedral angles, degrees.
    pub min_dihedral_deg: f64,
    /// Largest of the six interior dihedral angles, degrees.
    pub max_dihedral_deg: f64,
}

/// Quality of the tetrahedron `[a, b, c, d]`.
pub fn tet_quality(p: [Point3<f64>; 4]) -> TetQuality {
    let [a, b, c, d] = p;
    let (u, v, w) = (b - a, c - a, d - a);
    let six_v = u.cross(&v).dot(&w);
    let volume = six_v / 6.0;

    // Face normals (area-weighted, outward for a positive tet), face i opposite
    // vertex i.
    let faces: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
    let mut normals = [Vector3::zeros(); 4];
    let mut area_sum = 0.0;
    for (i, f) in faces.iter().enumerate() {
        let n = (p[f[1]] - p[f[0]]).cross(&(p[f[2]] - p[f[0]]));
        area_sum += 0.5 * n.norm();
        // Flip for an inverted tet so that the normals stay outward.
        normals[i] = if six_v < 0.0 { -n } else { n };
    }

    let radius_ratio = if six_v == 0.0 || area_sum == 0.0 {
        0.0
    } else {
        let r_in = 3.0 * volume.abs() / area_sum;
        let o = u.norm_squared() * v.cross(&w)
            + v.norm_squared() * w.cross(&u)
            + w.norm_squared() * u.cross(&v);
        let r_circ = o.norm() / (2.0 * six_v.abs());
        if r_circ > 0.0 && r_circ.is_finite() {
            (3.0 * r_in / r_circ).min(1.0)
        } else {
            0.0
        }
    };

    let mut min_dihedral_deg = f64::INFINITY;
    let mut max_dihedral_deg = f64::NEG_INFINITY;
    for i in 0..4 {
        for j in (i + 1)..4 {
            let (ni, nj) = (normals[i].norm(), normals[j].norm());
            if ni == 0.0 || nj == 0.0 {
                continue;
            }
            let cos = (normals[i].dot(&normals[j]) / (ni * nj)).clamp(-1.0, 1.0);
            let theta = 180.0 - cos.acos().to_degrees();
            min_dihedral_deg = min_dihedral_deg.min(theta);
            max_dihedral_deg = max_dihedral_deg.max(theta);
        }
    }
    if !min_dihedral_deg.is_finite() {
        // Every face is degenerate (all four points on a line or coincident).
        min_dihedral_deg = 0.0;
        max_dihedral_deg = 180.0;
    }
    TetQuality {
        volume,
        radius_ratio,
        min_dihedral_deg,
        max_dihedral_deg,
    }
}

/// Quality of every tetrahedron of `mesh`, in element order.
pub fn mesh_quality(mesh: &TetMesh) -> Vec<TetQuality> {
    tets_quality(&mesh.nodes, &mesh.tets)
}

/// Quality of every tetrahedron given as raw node indices. Tetrahedra that
/// name a node out of range get volume NaN and radius ratio 0 (they are
/// reported by [`super::validate`]).
pub fn tets_quality(nodes: &[Point3<f64>], tets: &[[u32; 4]]) -> Vec<TetQuality> {
    tets.iter()
        .map(|t| {
            if t.iter().any(|&i| i as usize >= nodes.len()) {
                TetQuality {
                    volume: f64::NAN,
                    radius_ratio: 0.0,
                    min_dihedral_deg: 0.0,
                    max_dihedral_deg: 180.0,
                }
            } else {
                tet_quality(t.map(|i| nodes[i as usize]))
            }
        })
        .collect()
}

/// Extremes and mean of the quality measures of a set of tetrahedra.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualitySummary {
    /// Sum of the signed volumes, m^3.
    pub total_volume: f64,
    /// Smallest signed volume, m^3.
    pub min_volume: f64,
    /// Largest signed volume, m^3.
    pub max_volume: f64,
    /// Smallest radius ratio.
    pub min_radius_ratio: f64,
    /// Mean radius ratio.
    pub mean_radius_ratio: f64,
    /// Smallest dihedral angle over all tets, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle over all tets, degrees.
    pub max_dihedral_deg: f64,
}

impl QualitySummary {
    /// Summarises `q`; `None` when `q` is empty.
    pub fn of(q: &[TetQuality]) -> Option<Self> {
        if q.is_empty() {
            return None;
        }
        let mut s = Self {
            total_volume: 0.0,
            min_volume: f64::INFINITY,
            max_volume: f64::NEG_INFINITY,
            min_radius_ratio: f64::INFINITY,
            mean_radius_ratio: 0.0,
            min_dihedral_deg: f64::INFINITY,
            max_dihedral_deg: f64::NEG_INFINITY,
        };
        for t in q {
            s.total_volume += t.volume;
            s.min_volume = s.min_volume.min(t.volume);
            s.max_volume = s.max_volume.max(t.volume);
            s.min_radius_ratio = s.min_radius_ratio.min(t.radius_ratio);
            s.mean_radius_ratio += t.radius_ratio;
            s.min_dihedral_deg = s.min_dihedral_deg.min(t.min_dihedral_deg);
            s.max_dihedral_deg = s.max_dihedral_deg.max(t.max_dihedral_deg);
        }
        s.mean_radius_ratio /= q.len() as f64;
        Some(s)
    }
}

/// A histogram of values over `[lo, hi]` in equal bins.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    /// Lower edge of the first bin.
    pub lo: f64,
    /// Upper edge of the last bin.
    pub hi: f64,
    /// Number of values in each bin; bin `k` covers
    /// `[lo + k h, lo + (k + 1) h)` with `h = (hi - lo) / bins`, the last bin
    /// also holds `hi`.
    pub counts: Vec<usize>,
    /// Values below `lo`, above `hi`, or NaN.
    pub outside: usize,
}

impl Histogram {
    /// Counts `values` into `bins` equal bins over `[lo, hi]` (`bins` at least
    /// 1; `hi > lo` expected, otherwise every value lands in the one bin or
    /// outside).
    pub fn new(values: impl IntoIterator<Item = f64>, lo: f64, hi: f64, bins: usize) -> Self {
        let bins = bins.max(1);
        let mut counts = vec![0usize; bins];
        let mut outside = 0;
        let width = hi - lo;
        for x in values {
            if !(x >= lo && x <= hi) {
                outside += 1;
            } else if width <= 0.0 {
                counts[0] += 1;
            } else {
                let k = (((x - lo) / width) * bins as f64) as usize;
                counts[k.min(bins - 1)] += 1;
            }
        }
        Self {
            lo,
            hi,
            counts,
            outside,
        }
    }

    /// Lower and upper edge of bin `k`.
    pub fn bin_edges(&self, k: usize) -> (f64, f64) {
        let h = (self.hi - self.lo) / self.counts.len() as f64;
        (self.lo + k as f64 * h, self.lo + (k + 1) as f64 * h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn regular() -> [Point3<f64>; 4] {
        [
            Point3::new(1.0, 1.0, 1.0),
            Point3::new(1.0, -1.0, -1.0),
            Point3::new(-1.0, 1.0, -1.0),
            Point3::new(-1.0, -1.0, 1.0),
        ]
    }

    #[test]
    fn regular_tet_is_one_with_equal_dihedrals() {
        let mut p = regular();
        let mut q = tet_quality(p);
        if q.volume < 0.0 {
            p.swap(2, 3);
            q = tet_quality(p);
        }
        // Edge sqrt(8): V = a^3 / (6 sqrt 2) = 8/3.
        assert!((q.volume - 8.0 / 3.0).abs() < 1e-12);
        assert!((q.radius_ratio - 1.0).abs() < 1e-12);
        let ideal = (1.0f64 / 3.0).acos().to_degrees();
        assert!((q.min_dihedral_deg - ideal).abs() < 1e-9);
        assert!((q.max_dihedral_deg - ideal).abs() < 1e-9);
        // Inversion flips the volume sign and keeps the shape measures.
        p.swap(0, 1);
        let r = tet_quality(p);
        assert!((r.volume + q.volume).abs() < 1e-12);
        assert!((r.radius_ratio - 1.0).abs() < 1e-12);
        assert!((r.min_dihedral_deg - ideal).abs() < 1e-9);
    }

    #[test]
    fn corner_tet_has_right_angles() {
        // The unit corner tet: three dihedrals of 90 deg at the corner edges,
        // three of acos(1/sqrt 3) = 54.74 deg at the far edges.
        let q = tet_quality([
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
        ]);
        assert!((q.volume - 1.0 / 6.0).abs() < 1e-15);
        assert!((q.max_dihedral_deg - 90.0).abs() < 1e-9);
        assert!((q.min_dihedral_deg - (1.0 / 3f64.sqrt()).acos().to_degrees()).abs() < 1e-9);
        // r = 3V/A = 0.5 / (1.5 + sqrt(3)/2), R = sqrt(3)/2.
        let r = 0.5 / (1.5 + 3f64.sqrt() / 2.0);
        let expect = 3.0 * r / (3f64.sqrt() / 2.0);
        assert!((q.radius_ratio - expect).abs() < 1e-12);
    }

    #[test]
    fn flat_and_collapsed_tets_are_finite() {
        // A sliver: four points on a plane (a square).
        let flat = tet_quality([
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        ]);
        assert_eq!(flat.volume, 0.0);
        assert_eq!(flat.radius_ratio, 0.0);
        assert!(flat.min_dihedral_deg.abs() < 1e-9);
        assert!((flat.max_dihedral_deg - 180.0).abs() < 1e-9);
        // All four points coincide.
        let p = Point3::new(0.1, 0.2, 0.3);
        let dot = tet_quality([p; 4]);
        assert_eq!(dot.volume, 0.0);
        assert_eq!(dot.radius_ratio, 0.0);
        assert!(dot.min_dihedral_deg.is_finite() && dot.max_dihedral_deg.is_finite());
        // A near-sliver has a small but positive ratio.
        let near = tet_quality([
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(1.0, 1.0, 1e-6),
        ]);
        assert!(near.radius_ratio > 0.0 && near.radius_ratio < 1e-4);
    }

    #[test]
    fn histogram_counts_every_value_once() {
        let h = Histogram::new(
            [0.0, 0.1, 0.5, 0.99, 1.0, 1.5, f64::NAN, -0.1],
            0.0,
            1.0,
            10,
        );
        assert_eq!(h.counts.iter().sum::<usize>() + h.outside, 8);
        assert_eq!(h.outside, 3);
        assert_eq!(h.counts[0], 1);
        assert_eq!(h.counts[1], 1);
        assert_eq!(h.counts[5], 1);
        assert_eq!(h.counts[9], 2);
        let (a, b) = h.bin_edges(5);
        assert!((a - 0.5).abs() < 1e-15 && (b - 0.6).abs() < 1e-15);
    }

    #[test]
    fn cube_mesh_quality() {
        let mesh = crate::mesh::blocks::cube(2.0, 3);
        let q = mesh_quality(&mesh);
        let s = QualitySummary::of(&q).unwrap();
        assert!((s.total_volume - 8.0).abs() < 1e-12);
        // Kuhn tets: dihedrals of 45, 60 and 90 degrees.
        assert!((s.min_dihedral_deg - 45.0).abs() < 1e-9);
        assert!((s.max_dihedral_deg - 90.0).abs() < 1e-9);
        assert!(s.min_radius_ratio > 0.7 && s.min_radius_ratio < 0.8);
    }
}
