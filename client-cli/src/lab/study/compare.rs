//! Accuracy of a run against the reference at common material points.
//!
//! Different presets have different meshes, so points are matched by rest
//! position: each reference surface vertex inside the error region is mapped
//! to the nearest point of the configuration's rest surface (a triangle and
//! barycentric weights), and the configuration's displacement there is the
//! barycentric blend of its vertex displacements. The error at a step is the
//! distance between that displacement and the reference vertex's. Steps match
//! by index (all runs of a comparison share the scenario and `dt`).
//!
//! The error region is the ball of radius [`ERROR_RADIUS_M`] about the
//! fissure centre: the spatulas, the fissure walls they open and the cortex
//! around it. Forces compare the net force of the tissue on each instrument
//! at every step.

use super::config::FISSURE_CENTRE_M;
use super::driver::RunResult;
use nalgebra::{Point3, Vector3};
use serde::Serialize;

/// Radius of the error region about the fissure centre, m.
pub const ERROR_RADIUS_M: f64 = 0.035;

/// A point on a triangle: vertex indices and barycentric weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// Surface vertices.
    pub vertices: [u32; 3],
    /// Weights, summing to 1.
    pub weights: [f64; 3],
    /// Distance from the query point, m.
    pub distance: f64,
}

/// Closest point of triangle `abc` to `p`, as barycentric weights (Ericson,
/// Real-Time Collision Detection, 5.1.5).
pub fn closest_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> [f64; 3] {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    [1.0 - v - w, v, w]
}

/// A uniform grid of triangles (by bounding box) for nearest-point queries.
pub struct TriangleGrid<'a> {
    positions: &'a [Point3<f64>],
    triangles: &'a [[u32; 3]],
    lo: Point3<f64>,
    cell: f64,
    dims: [usize; 3],
    cells: Vec<Vec<u32>>,
}

impl<'a> TriangleGrid<'a> {
    /// Buckets `triangles` over `positions` in cubic cells of `cell` m.
    pub fn new(positions: &'a [Point3<f64>], triangles: &'a [[u32; 3]], cell: f64) -> Self {
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        for p in positions {
            for i in 0..3 {
                lo[i] = lo[i].min(p[i]);
                hi[i] = hi[i].max(p[i]);
            }
        }
        let dims = [0, 1, 2].map(|i| (((hi[i] - lo[i]) / cell).floor() as usize + 1).max(1));
        let mut cells = vec![Vec::new(); dims[0] * dims[1] * dims[2]];
        for (t, tri) in triangles.iter().enumerate() {
            let mut a = [usize::MAX; 3];
            let mut b = [0usize; 3];
            for &v in tri {
                let p = positions[v as usize];
                for i in 0..3 {
                    let c = (((p[i] - lo[i]) / cell).floor().max(0.0) as usize).min(dims[i] - 1);
                    a[i] = a[i].min(c);
                    b[i] = b[i].max(c);
                }
            }
            for x in a[0]..=b[0] {
                for y in a[1]..=b[1] {
                    for z in a[2]..=b[2] {
                        cells[(x * dims[1] + y) * dims[2] + z].push(t as u32);
                    }
                }
            }
        }
        Self {
            positions,
            triangles,
            lo,
            cell,
            dims,
            cells,
        }
    }

    /// The nearest point of the surface to `p`.
    pub fn nearest(&self, p: &Point3<f64>) -> Option<SurfacePoint> {
        let c = [0, 1, 2].map(|i| {
            let f = ((p[i] - self.lo[i]) / self.cell).floor();
            f.clamp(0.0, (self.dims[i] - 1) as f64) as i64
        });
        let max_ring = *self.dims.iter().max().unwrap_or(&1) as i64;
        let mut best: Option<SurfacePoint> = None;
        for r in 0..=max_ring {
            for x in (c[0] - r)..=(c[0] + r) {
                for y in (c[1] - r)..=(c[1] + r) {
                    for z in (c[2] - r)..=(c[2] + r) {
                        let on_ring =
                            (x - c[0]).abs() == r || (y - c[1]).abs() == r || (z - c[2]).abs() == r;
                        if !on_ring
                            || x < 0
                            || y < 0
                            || z < 0
                            || x >= self.dims[0] as i64
                            || y >= self.dims[1] as i64
                            || z >= self.dims[2] as i64
                        {
                            continue;
                        }
                        let idx =
                            (x as usize * self.dims[1] + y as usize) * self.dims[2] + z as usize;
                        for &t in &self.cells[idx] {
                            let tri = self.triangles[t as usize];
                            let [a, b, cc] = tri.map(|v| self.positions[v as usize]);
                            let w = closest_on_triangle(p, &a, &b, &cc);
                            let q = a.coords * w[0] + b.coords * w[1] + cc.coords * w[2];
                            let d = (q - p.coords).norm();
                            if best.is_none_or(|b| d < b.distance) {
                                best = Some(SurfacePoint {
                                    vertices: tri,
                                    weights: w,
                                    distance: d,
                                });
                            }
                        }
                    }
                }
            }
            // Cells beyond ring r are at least r cells away.
            if let Some(b) = best
                && b.distance <= r as f64 * self.cell
            {
                break;
            }
        }
        best
    }
}

/// Errors of one run against the reference.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Errors {
    /// RMS surface displacement error over the region's points and all steps, mm.
    pub rms_mm: f64,
    /// Largest surface displacement error, mm.
    pub max_mm: f64,
    /// Largest reference displacement in the region, mm (scale of the above).
    pub ref_max_mm: f64,
    /// RMS over the steps of the net-force error of each instrument, N.
    pub force_rms_n: [f64; 2],
    /// The same relative to the reference's peak force magnitude, %.
    pub force_rms_pct: [f64; 2],
    /// Net-force error at the last step, % of the reference's there.
    pub final_force_pct: [f64; 2],
    /// Region points compared.
    pub points: usize,
    /// Mean distance from a reference point to its match, mm (how far the
    /// meshes' rest surfaces differ there).
    pub mean_match_mm: f64,
    /// Root mean square of the same, mm.
    pub rms_match_mm: f64,
    /// Its largest, mm.
    pub max_match_mm: f64,
}

/// The reference surface vertices in the error region.
pub fn region_vertices(reference: &RunResult) -> Vec<usize> {
    let c = Point3::from(FISSURE_CENTRE_M);
    (0..reference.rest_surface.len())
        .filter(|&i| (reference.rest_surface[i] - c).norm() <= ERROR_RADIUS_M)
        .collect()
}

/// Compares `run` with `reference` (both with surfaces kept).
pub fn compare(reference: &RunResult, region: &[usize], run: &RunResult) -> Errors {
    let grid = TriangleGrid::new(&run.rest_surface, &run.triangles, 0.005);
    let matches: Vec<SurfacePoint> = region
        .iter()
        .filter_map(|&i| grid.nearest(&reference.rest_surface[i]))
        .collect();
    let steps = reference.surface_u.len().min(run.surface_u.len());
    let (mut sum2, mut count, mut max, mut ref_max) = (0.0, 0usize, 0.0f64, 0.0f64);
    for k in 0..steps {
        let ru = &reference.surface_u[k];
        let cu = &run.surface_u[k];
        for (&i, m) in region.iter().zip(&matches) {
            let u: Vector3<f64> = (0..3)
                .map(|j| cu[m.vertices[j] as usize] * m.weights[j])
                .sum();
            let e = (u - ru[i]).norm();
            if !e.is_finite() {
                max = f64::INFINITY;
            }
            sum2 += e * e;
            count += 1;
            max = max.max(e);
            ref_max = ref_max.max(ru[i].norm());
        }
    }
    let mut out = Errors {
        rms_mm: (sum2 / count.max(1) as f64).sqrt() * 1e3,
        max_mm: max * 1e3,
        ref_max_mm: ref_max * 1e3,
        points: matches.len(),
        mean_match_mm: matches.iter().map(|m| m.distance).sum::<f64>()
            / matches.len().max(1) as f64
            * 1e3,
        rms_match_mm: (matches.iter().map(|m| m.distance.powi(2)).sum::<f64>()
            / matches.len().max(1) as f64)
            .sqrt()
            * 1e3,
        max_match_mm: matches.iter().map(|m| m.distance).fold(0.0, f64::max) * 1e3,
        ..Errors::default()
    };
    let fsteps = reference.step_force.len().min(run.step_force.len());
    for i in 0..2 {
        let mut s2 = 0.0;
        let mut peak: f64 = 0.0;
        for k in 0..fsteps {
            let (Some(r), Some(c)) = (reference.step_force[k].get(i), run.step_force[k].get(i))
            else {
                continue;
            };
            s2 += (c - r).norm_squared();
            peak = peak.max(r.norm());
        }
        let rms = (s2 / fsteps.max(1) as f64).sqrt();
        out.force_rms_n[i] = rms;
        out.force_rms_pct[i] = 100.0 * rms / peak.max(f64::MIN_POSITIVE);
        let (rf, cf) = (reference.final_force(i), run.final_force(i));
        out.final_force_pct[i] = 100.0 * (cf - rf).norm() / rf.norm().max(f64::MIN_POSITIVE);
    }
    out
}

#[cfg(test)]
/// A run at rest (no step) on surface `pos`, `triangles`.
pub(super) fn at_rest(pos: Vec<Point3<f64>>, triangles: Vec<[u32; 3]>) -> RunResult {
    RunResult {
        config: super::config::Config::baseline(),
        tets: 0,
        nodes: pos.len(),
        rest_surface: pos,
        triangles,
        step_t: Vec::new(),
        step_force: Vec::new(),
        surface_u: Vec::new(),
        step_ms: Vec::new(),
        collision_ms: Vec::new(),
        step_failed: Vec::new(),
        iterations: Vec::new(),
        sample_t: Vec::new(),
        sample_force: Vec::new(),
        sample_us: Vec::new(),
        min_det_f: 1.0,
        finite: true,
        failed_steps: 0,
        failure: None,
        dropped_outside_roi: 0,
        setup_ms: 0.0,
        backend_used: String::new(),
        has_local_model: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions_of_a_triangle() {
        let a = Point3::new(0.0, 0.0, 0.0);
        let b = Point3::new(1.0, 0.0, 0.0);
        let c = Point3::new(0.0, 1.0, 0.0);
        // Above the interior: the projection.
        let w = closest_on_triangle(&Point3::new(0.25, 0.25, 3.0), &a, &b, &c);
        assert!((w[0] - 0.5).abs() < 1e-12 && (w[1] - 0.25).abs() < 1e-12);
        // Beyond vertex b.
        assert_eq!(
            closest_on_triangle(&Point3::new(2.0, -1.0, 0.0), &a, &b, &c),
            [0.0, 1.0, 0.0]
        );
        // Beyond the hypotenuse: its midpoint.
        let w = closest_on_triangle(&Point3::new(1.0, 1.0, 0.0), &a, &b, &c);
        assert!((w[1] - 0.5).abs() < 1e-12 && (w[2] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn rest_surfaces_a_uniform_offset_apart_match_at_that_distance() {
        // A 40 mm cube about the fissure centre, and the same cube with
        // every face moved out by 0.2 mm: every point of the first (faces,
        // edges and corners) lies 0.2 mm from the second's surface.
        let cube = fissure_engine::mesh::blocks::cube(0.04, 4);
        let surf = cube.boundary();
        let mut pos = Vec::new();
        surf.gather(&cube.nodes, &mut pos);
        let mid = pos.iter().map(|p| p.coords).sum::<Vector3<f64>>() / pos.len() as f64;
        let centre = Point3::from(FISSURE_CENTRE_M);
        let (side, offset) = (0.04, 2e-4);
        let at = |k: f64| -> Vec<Point3<f64>> {
            pos.iter().map(|p| centre + (p.coords - mid) * k).collect()
        };
        let inner = at_rest(at(1.0), surf.triangles.clone());
        let outer = at_rest(at((side + 2.0 * offset) / side), surf.triangles.clone());
        let region = region_vertices(&inner);
        assert_eq!(
            region.len(),
            pos.len(),
            "the whole cube is within the region"
        );
        let e = compare(&inner, &region, &outer);
        assert_eq!(e.points, pos.len());
        for d in [e.mean_match_mm, e.rms_match_mm, e.max_match_mm] {
            assert!((d - 0.2).abs() < 1e-9, "{e:?}");
        }
        // The same surface matches itself at zero distance.
        let e = compare(&inner, &region, &inner);
        assert!(e.max_match_mm < 1e-12, "{e:?}");
    }

    #[test]
    fn grid_nearest_equals_brute_force() {
        let cube = fissure_engine::mesh::blocks::cube(0.04, 4);
        let surf = cube.boundary();
        let mut pos = Vec::new();
        surf.gather(&cube.nodes, &mut pos);
        let grid = TriangleGrid::new(&pos, &surf.triangles, 0.005);
        for i in 0..50 {
            let s = i as f64 * 0.37;
            let p = Point3::new(
                0.02 + 0.03 * s.sin(),
                0.02 + 0.03 * (1.3 * s).cos(),
                0.02 + 0.025 * (0.7 * s).sin(),
            );
            let got = grid.nearest(&p).expect("non-empty surface");
            let brute = surf
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|v| pos[v as usize]);
                    let w = closest_on_triangle(&p, &a, &b, &c);
                    (a.coords * w[0] + b.coords * w[1] + c.coords * w[2] - p.coords).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                (got.distance - brute).abs() < 1e-12,
                "point {i}: grid {} brute {brute}",
                got.distance
            );
        }
    }
}
