//! What a deformation frame did to the tissue: the retraction pressure
//! under each instrument and the tissue's largest principal strain, the
//! measures a session is assessed by (thresholds in
//! [`crate::scene::assessment`]).
//!
//! # Retraction pressure
//!
//! The instrument's rows push the tissue: a row with multiplier `lambda`
//! (N) pushes its tissue point along its direction `d`, shared among the
//! nodes of its triangle by the point's weights `w_a` (a node row: weight
//! 1 on its node). A surface
//! vertex's contact force is `F_v = sum lambda w_a d` over the instrument's
//! unilateral rows and the paper rule's bilateral ones (friction's tangent
//! rows carry no pressure), its normal force `f_v = |F_v|`. Its tributary
//! area is a third of each of its surface triangles' rest areas, projected
//! on the plane the force presses: `A_v = sum_t (A_t / 3) max(0, -n_t .
//! F_v / f_v)`. That is the lumped load of linear triangles, so a uniform
//! pressure `p` on a flat face gives `f_v = p A_v` exactly, at the face's
//! edges too (the side faces, parallel to the force, add no area). Then
//!
//! * the contact area `A = sum A_v` over the vertices pushed, m^2;
//! * the mean pressure `p_mean = sum f_v / A`, Pa (what a sensor under the
//!   blade reads, and what the thresholds are stated for);
//! * the peak pressure `max f_v / A_v`, Pa (mesh-dependent at the plate's
//!   edges, where the exact pressure is singular).
//!
//! Over a session ([`PressureClock`]) a frame's mean pressure holds until
//! the next frame (sample and hold): the time at or above the warning
//! pressure and the pressure-time product `integral p_mean dt` (Pa s) are
//! sums over frame intervals, exact for a piecewise-constant record.
//!
//! # Strain
//!
//! A linear tetrahedron's deformation gradient is constant: with its rest
//! edge matrix `D = [x1 - x0, x2 - x0, x3 - x0]` and the displacements'
//! `D_u = [u1 - u0, u2 - u0, u3 - u0]`, `H = grad u = D_u D^-1` and
//! `F = I + H`. The Green-Lagrange strain `E = (F^T F - I) / 2 = (H + H^T +
//! H^T H) / 2` (exact for any displacement, rotation-free); its largest
//! eigenvalue (closed form for a symmetric 3x3, trigonometric) is the
//! tetrahedron's largest principal strain. The strained volume is the rest
//! volume of the tetrahedra at or above the threshold, m^3.
//!
//! Most of the brain is far below any threshold, and a bound from the
//! nodes' displacement differences alone skips it: `|H| <= |D_u|_F
//! |D^-1|_F` and the largest eigenvalue of `E` is at most `|H| + |H|^2 /
//! 2`; a tetrahedron whose bound is below both the threshold and the
//! largest strain found so far cannot change either. The last frame's
//! worst tetrahedron is evaluated first, so that the largest strain is
//! about known from the start, and Gershgorin's discs on `E` spare the
//! eigenvalue of most of the rest. The scan runs in fixed chunks on the
//! rayon pool, reduced in order (the answer is the same on any number of
//! threads). Below [`STRAIN_RESOLUTION`] (0.1 %) the
//! maximum is not sought exactly (tissue strained by less is all alike to
//! the assessment). (A rigid translation of the brain does not
//! weaken the bound; a large rigid rotation does, not the answer.)
//!
//! Written here rather than taken from a crate: the per-tetrahedron work is
//! a handful of fixed-size products over a precomputed `D^-1`, and the
//! skipping bound is what keeps it within the step's budget.

use crate::fem::RowKind;
use crate::mesh::{BoundarySurface, TetMesh};
use crate::scene::assessment::AssessmentSpec;
use crate::sim::core::rows::Row;
use nalgebra::{Matrix3, Point3, Unit, Vector3};
use rayon::prelude::*;

/// Retraction pressure under one instrument in one frame, and its session
/// sums up to that frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pressure {
    /// Surface area the instrument pushes, m^2.
    pub contact_area_m2: f64,
    /// Normal force it pushes with, N.
    pub normal_force_n: f64,
    /// Largest vertex pressure, Pa.
    pub peak_pa: f64,
    /// Normal force per contact area, Pa (0 without contact).
    pub mean_pa: f64,
    /// Session time with the mean pressure at or above the warning level,
    /// up to this frame, s.
    pub time_above_s: f64,
    /// Mean pressure integrated over the session up to this frame, Pa s.
    pub pressure_time_pa_s: f64,
}

/// The tissue's strain in one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StrainMeasure {
    /// Largest principal Green-Lagrange strain over the tetrahedra.
    pub max_principal: f64,
    /// The rest centroid of the tetrahedron that has it, m.
    pub at_m: Point3<f64>,
    /// Rest volume of the tetrahedra at or above `threshold`, m^3.
    pub volume_above_m3: f64,
    /// The strain the volume counts from.
    pub threshold: f64,
    /// The tetrahedron with the largest strain.
    pub tet: usize,
}

/// The picture of a frame's strain: the surface as it is and, per surface
/// vertex, the largest principal strain of the tetrahedra around it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StrainPicture {
    /// Surface vertex positions, m, single precision.
    pub positions: Vec<[f32; 3]>,
    /// Largest principal strain per surface vertex.
    pub strain: Vec<f32>,
}

/// The rest geometry the measures need, computed once per model.
#[derive(Debug, Clone)]
pub struct InjuryGeometry {
    /// Per tetrahedron: its nodes.
    tets: Vec<[u32; 4]>,
    /// Per tetrahedron: `D^-1` (row-major), 1/m.
    inverse: Vec<[f64; 9]>,
    /// Per tetrahedron: rest volume, m^3.
    volume_m3: Vec<f64>,
    /// Per tetrahedron: `|D^-1|_F^2`, 1/m^2 (the strain bound's factor,
    /// squared).
    reach2: Vec<f64>,
    /// The tetrahedra with a surface vertex (those a picture shows).
    surface_tets: Vec<u32>,
    /// Per tetrahedron: rest centroid, m.
    centroid: Vec<Point3<f64>>,
    /// Per surface vertex, the range of `faces` of its triangles.
    face_start: Vec<u32>,
    /// Per surface vertex and triangle: a third of the triangle's rest
    /// area times its outward unit normal, m^2.
    faces: Vec<Vector3<f64>>,
    /// Volume node -> surface vertex (`u32::MAX`: interior).
    from_volume: Vec<u32>,
}

impl InjuryGeometry {
    /// The geometry of `mesh` (rest positions, m) and its boundary
    /// `surface`; `from_volume` maps volume nodes to surface vertices.
    pub fn new(mesh: &TetMesh, surface: &BoundarySurface, from_volume: &[u32]) -> Self {
        let n = mesh.tets.len();
        let mut inverse = Vec::with_capacity(n);
        let mut volume_m3 = Vec::with_capacity(n);
        let mut centroid = Vec::with_capacity(n);
        let mut reach2 = Vec::with_capacity(n);
        for t in &mesh.tets {
            let x = t.map(|i| mesh.nodes[i as usize]);
            let d = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
            // A mesh's tetrahedra are checked positively oriented; a
            // degenerate one contributes no strain rather than NaN.
            let inv = d.try_inverse().unwrap_or_else(Matrix3::zeros);
            let mut row_major = [0.0; 9];
            for r in 0..3 {
                for c in 0..3 {
                    row_major[3 * r + c] = inv[(r, c)];
                }
            }
            inverse.push(row_major);
            reach2.push(inv.norm_squared());
            volume_m3.push(d.determinant().abs() / 6.0);
            centroid.push(Point3::from(
                (x[0].coords + x[1].coords + x[2].coords + x[3].coords) / 4.0,
            ));
        }
        let ns = surface.to_volume.len();
        let mut count = vec![0u32; ns + 1];
        for tri in &surface.triangles {
            for &v in tri {
                count[v as usize + 1] += 1;
            }
        }
        for i in 0..ns {
            count[i + 1] += count[i];
        }
        let face_start = count.clone();
        let mut faces = vec![Vector3::zeros(); surface.triangles.len() * 3];
        for tri in &surface.triangles {
            let p = tri.map(|s| mesh.nodes[surface.to_volume[s as usize] as usize]);
            let third = (p[1] - p[0]).cross(&(p[2] - p[0])) / 6.0;
            for &v in tri {
                faces[count[v as usize] as usize] = third;
                count[v as usize] += 1;
            }
        }
        Self {
            tets: mesh.tets.clone(),
            inverse,
            volume_m3,
            reach2,
            surface_tets: (0..n as u32)
                .filter(|&k| {
                    mesh.tets[k as usize]
                        .iter()
                        .any(|&v| from_volume.get(v as usize).is_some_and(|&s| s != u32::MAX))
                })
                .collect(),
            centroid,
            face_start,
            faces,
            from_volume: from_volume.to_vec(),
        }
    }

    /// Tributary area of surface vertex `v` pressed along unit `d` (the
    /// force on the tissue), m^2.
    pub fn tributary_area_m2(&self, v: u32, d: &Vector3<f64>) -> f64 {
        let range = self.face_start[v as usize] as usize..self.face_start[v as usize + 1] as usize;
        self.faces[range].iter().map(|f| (-f.dot(d)).max(0.0)).sum()
    }

    /// The pressure instrument `owner` puts on the tissue through `rows`
    /// with multipliers `lambda` (N), without session sums. `force` is a
    /// workspace of one entry per surface vertex (left zeroed).
    pub fn pressure(
        &self,
        rows: &[Row],
        lambda: &[f64],
        owner: u16,
        force: &mut Vec<Vector3<f64>>,
    ) -> Pressure {
        force.clear();
        force.resize(self.face_start.len() - 1, Vector3::zeros());
        let mut touched: Vec<u32> = Vec::new();
        for (r, &l) in rows.iter().zip(lambda) {
            if r.owner != owner || l == 0.0 {
                continue;
            }
            let row = &r.row;
            if !matches!(row.kind, RowKind::Unilateral | RowKind::Bilateral) {
                continue;
            }
            // A point row's own triangle has the fixed nodes too (the
            // solver's row leaves them out).
            let (nodes, weights) = if r.triangle.0[0] == u32::MAX {
                ([row.node, u32::MAX, u32::MAX], [row.weight, 0.0, 0.0])
            } else {
                r.triangle
            };
            for (node, w) in nodes.into_iter().zip(weights) {
                let Some(&s) = self.from_volume.get(node as usize) else {
                    continue;
                };
                if s == u32::MAX || w == 0.0 {
                    continue;
                }
                touched.push(s);
                force[s as usize] += row.dir * (l * w);
            }
        }
        touched.sort_unstable();
        touched.dedup();
        let mut p = Pressure::default();
        for &s in &touched {
            let f = std::mem::take(&mut force[s as usize]);
            let Some((d, f)) = Unit::try_new_and_get(f, 0.0) else {
                continue;
            };
            let a = self.tributary_area_m2(s, &d);
            if a <= 0.0 {
                continue;
            }
            p.contact_area_m2 += a;
            p.normal_force_n += f;
            p.peak_pa = p.peak_pa.max(f / a);
        }
        if p.contact_area_m2 > 0.0 {
            p.mean_pa = p.normal_force_n / p.contact_area_m2;
        }
        p
    }

    /// The strain of displacements `u` (m, one per volume node): its
    /// largest principal value and the volume at or above `threshold`.
    /// `hint` is a tetrahedron evaluated first (the last frame's worst:
    /// the maximum is then about known early, and the bound skips nearly
    /// every other tetrahedron). With `per_vertex` (one
    /// entry per surface vertex), the largest principal strain of the
    /// tetrahedra around each surface vertex instead, every one of them
    /// evaluated (the measure then covers only those tetrahedra: its volume
    /// is 0).
    pub fn strain(
        &self,
        u: &[Vector3<f64>],
        threshold: f64,
        hint: usize,
        per_vertex: Option<&mut [f32]>,
    ) -> StrainMeasure {
        let (best, best_tet, volume) = match per_vertex {
            Some(v) => self.picture_scan(u, v),
            None => {
                let start = match hint < self.tets.len() {
                    true => Scan {
                        best: self.principal(u, hint),
                        best_tet: hint,
                        volume: 0.0,
                    },
                    false => Scan::default(),
                };
                // Fixed chunks, reduced in order: the answer does not
                // depend on the threads.
                let chunks: Vec<Scan> = self
                    .tets
                    .par_chunks(STRAIN_CHUNK)
                    .enumerate()
                    .map(|(c, tets)| self.scan(u, threshold, start.best, c * STRAIN_CHUNK, tets))
                    .collect();
                let mut all = start;
                for c in chunks {
                    if c.best > all.best {
                        all.best = c.best;
                        all.best_tet = c.best_tet;
                    }
                    all.volume += c.volume;
                }
                (all.best, all.best_tet, all.volume)
            }
        };
        StrainMeasure {
            max_principal: if best.is_finite() { best } else { 0.0 },
            at_m: self
                .centroid
                .get(best_tet)
                .copied()
                .unwrap_or_else(Point3::origin),
            volume_above_m3: volume,
            threshold,
            tet: best_tet,
        }
    }

    /// The largest principal strain of tetrahedron `k`.
    fn principal(&self, u: &[Vector3<f64>], k: usize) -> f64 {
        let t = &self.tets[k];
        largest_eigenvalue(&green_lagrange(&self.inverse[k], t.map(|i| &u[i as usize])))
    }

    /// The tetrahedra `first..` of `tets`: the largest strain above `known`
    /// (and its tetrahedron), and the volume at or above `threshold`,
    /// skipping every tetrahedron that can change neither.
    fn scan(
        &self,
        u: &[Vector3<f64>],
        threshold: f64,
        known: f64,
        first: usize,
        tets: &[[u32; 4]],
    ) -> Scan {
        let mut out = Scan {
            best: known,
            ..Scan::default()
        };
        // The level a tetrahedron must reach to count, and the same on
        // `|H|`: `h + h^2 / 2 >= l` where `h >= sqrt(1 + 2 l) - 1`,
        // compared squared.
        let level = |best: f64| threshold.min(best.max(STRAIN_RESOLUTION));
        let h_lim2 = |l: f64| {
            if l > 0.0 {
                let h = (1.0 + 2.0 * l).sqrt() - 1.0;
                h * h
            } else {
                -1.0
            }
        };
        let mut l = level(out.best);
        let mut lim2 = h_lim2(l);
        for (j, t) in tets.iter().enumerate() {
            let k = first + j;
            // |H|_F^2 <= |D_u|_F^2 |D^-1|_F^2: the node displacements'
            // differences alone (a rigid translation costs nothing).
            let u0 = &u[t[0] as usize];
            let du2: f64 = t[1..]
                .iter()
                .map(|&i| (u[i as usize] - u0).norm_squared())
                .sum();
            if du2 * self.reach2[k] < lim2 {
                continue;
            }
            let e = green_lagrange(&self.inverse[k], t.map(|i| &u[i as usize]));
            // Gershgorin's discs bound the eigenvalue more tightly still.
            if gershgorin_max(&e) < l {
                continue;
            }
            let e1 = largest_eigenvalue(&e);
            if e1 > out.best {
                out.best = e1;
                out.best_tet = k;
                l = level(out.best);
                lim2 = h_lim2(l);
            }
            if e1 >= threshold {
                out.volume += self.volume_m3[k];
            }
        }
        out
    }

    /// Every tetrahedron at the surface: the largest principal strain of
    /// those around each surface vertex into `v`, and their largest.
    fn picture_scan(&self, u: &[Vector3<f64>], v: &mut [f32]) -> (f64, usize, f64) {
        v.fill(f32::NEG_INFINITY);
        let (mut best, mut best_tet) = (f64::NEG_INFINITY, 0);
        for &k in &self.surface_tets {
            let k = k as usize;
            let e1 = self.principal(u, k);
            if e1 > best {
                best = e1;
                best_tet = k;
            }
            for &node in &self.tets[k] {
                let s = self.from_volume[node as usize];
                if s != u32::MAX {
                    let slot = &mut v[s as usize];
                    *slot = slot.max(e1 as f32);
                }
            }
        }
        (best, best_tet, 0.0)
    }
}

/// Tetrahedra a task of the strain's scan takes.
const STRAIN_CHUNK: usize = 4096;

/// What a scan of tetrahedra found.
#[derive(Debug, Clone, Copy)]
struct Scan {
    best: f64,
    best_tet: usize,
    volume: f64,
}

impl Default for Scan {
    fn default() -> Self {
        Self {
            best: f64::NEG_INFINITY,
            best_tet: 0,
            volume: 0.0,
        }
    }
}

/// An upper bound of a symmetric matrix's largest eigenvalue (Gershgorin's
/// discs).
fn gershgorin_max(e: &Matrix3<f64>) -> f64 {
    (0..3)
        .map(|i| {
            e[(i, i)]
                + (0..3)
                    .filter(|&j| j != i)
                    .map(|j| e[(i, j)].abs())
                    .sum::<f64>()
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Below this, the largest principal strain is not sought exactly: a
/// tetrahedron whose bound is under it (and under the threshold) is
/// skipped even when nothing larger was found, so a frame whose tissue is
/// nowhere strained by 0.1 % reports the largest strain among those it
/// evaluated (at most this).
pub const STRAIN_RESOLUTION: f64 = 1e-3;

/// `E = (H + H^T + H^T H) / 2` with `H = D_u D^-1`, for a tetrahedron's
/// node displacements `u` (m) and `D^-1` (row-major, 1/m).
fn green_lagrange(inv: &[f64; 9], u: [&Vector3<f64>; 4]) -> Matrix3<f64> {
    let du = Matrix3::from_columns(&[u[1] - u[0], u[2] - u[0], u[3] - u[0]]);
    let dinv = Matrix3::from_row_slice(inv);
    let h = du * dinv;
    (h + h.transpose() + h.transpose() * h) * 0.5
}

/// The largest eigenvalue of a symmetric 3x3 matrix, in closed form: with
/// `q = tr/3`, `p = sqrt(|A - qI|_F^2 / 6)` and `r = det((A - qI)/p) / 2`,
/// it is `q + 2 p cos(acos(r) / 3)`.
pub fn largest_eigenvalue(a: &Matrix3<f64>) -> f64 {
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = (a[(0, 0)] + a[(1, 1)] + a[(2, 2)]) / 3.0;
    let p2 =
        (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * off;
    if p2 <= f64::MIN_POSITIVE {
        return q;
    }
    let p = (p2 / 6.0).sqrt();
    let b = (a - Matrix3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    q + 2.0 * p * (r.acos() / 3.0).cos()
}

/// The session sums of each instrument's pressure: a frame's mean pressure
/// holds until the next frame.
#[derive(Debug, Clone, Default)]
pub struct PressureClock {
    /// The last frame's time (s) and each instrument's mean pressure (Pa)
    /// and sums.
    last: Option<(f64, Vec<Pressure>)>,
}

impl PressureClock {
    /// Adds the interval since the last frame (held at its pressures) to
    /// the sums, and gives `now`'s pressures (at `t_s`) the sums so far;
    /// `warn_pa` is the pressure the time above counts from. A frame at or
    /// before the last one's time adds nothing.
    pub fn tick(&mut self, t_s: f64, now: &mut [Pressure], warn_pa: f64) {
        if let Some((t0, last)) = &self.last {
            let dt = (t_s - t0).max(0.0);
            for (p, q) in now.iter_mut().zip(last) {
                p.time_above_s = q.time_above_s + if q.mean_pa >= warn_pa { dt } else { 0.0 };
                p.pressure_time_pa_s = q.pressure_time_pa_s + q.mean_pa * dt;
            }
        }
        self.last = Some((t_s, now.to_vec()));
    }
}

/// The measures of a session's frames: the rest geometry, the pressure
/// sums, and when the next strain picture is due.
#[derive(Debug, Clone)]
pub struct InjuryStage {
    geometry: std::sync::Arc<InjuryGeometry>,
    thresholds: AssessmentSpec,
    clock: PressureClock,
    /// The largest strain pictured so far this session.
    pictured: f64,
    /// The last frame's worst tetrahedron.
    worst_tet: usize,
    force: Vec<Vector3<f64>>,
}

/// A strain picture is sent when the session's largest strain reaches this
/// factor of the last one pictured.
pub const PICTURE_GROWTH: f64 = 1.25;

/// No picture below this strain.
pub const PICTURE_FLOOR: f64 = 0.01;

impl InjuryStage {
    /// The measures of `geometry`'s tissue against `thresholds`.
    pub fn new(geometry: std::sync::Arc<InjuryGeometry>, thresholds: AssessmentSpec) -> Self {
        Self {
            geometry,
            thresholds,
            clock: PressureClock::default(),
            pictured: 0.0,
            worst_tet: 0,
            force: Vec::new(),
        }
    }

    /// Back to the start of a session (sums and pictures from zero).
    pub fn reset(&mut self) {
        self.clock = PressureClock::default();
        self.pictured = 0.0;
    }

    /// The measures of the frame at `t_s`: each of `instruments`
    /// instruments' pressure through `rows` with multipliers `lambda` (N),
    /// with the session sums; the strain of displacements `u` (m, per
    /// volume node); and the strain picture on `surface` (m) when one is
    /// due.
    pub fn measure(
        &mut self,
        t_s: f64,
        rows: &[Row],
        lambda: &[f64],
        instruments: usize,
        u: &[Vector3<f64>],
        surface: &[Point3<f64>],
    ) -> (Vec<Pressure>, StrainMeasure, Option<StrainPicture>) {
        let mut pressures: Vec<Pressure> = (0..instruments)
            .map(|k| {
                self.geometry
                    .pressure(rows, lambda, k as u16, &mut self.force)
            })
            .collect();
        self.clock
            .tick(t_s, &mut pressures, self.thresholds.pressure_pa.warn);
        let warn = self.thresholds.strain.warn;
        let strain = self.geometry.strain(u, warn, self.worst_tet, None);
        self.worst_tet = strain.tet;
        let due = strain.max_principal >= PICTURE_FLOOR
            && strain.max_principal >= self.pictured * PICTURE_GROWTH;
        let picture = due.then(|| {
            self.pictured = strain.max_principal;
            let mut field = vec![0.0f32; surface.len()];
            self.geometry.strain(u, warn, strain.tet, Some(&mut field));
            StrainPicture {
                positions: surface
                    .iter()
                    .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                    .collect(),
                strain: field,
            }
        });
        (pressures, strain, picture)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, SymmetricEigen};

    /// Numbers uniform in [-1, 1) from `seed` (a linear congruential
    /// generator: reproducible, nothing to install).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut unit = crate::test_rng::unit(seed);
        move || unit() * 2.0 - 1.0
    }

    /// The closed form equals nalgebra's symmetric eigen-solver, on
    /// random, diagonal, repeated and zero matrices.
    #[test]
    fn the_closed_form_eigenvalue_equals_an_iterative_solver() {
        let mut next = uniform(7);
        let mut cases = vec![
            Matrix3::zeros(),
            Matrix3::identity() * 0.3,
            Matrix3::from_diagonal(&Vector3::new(0.1, 0.1, -0.2)),
        ];
        for _ in 0..500 {
            let m = Matrix3::from_fn(|_, _| next());
            cases.push((m + m.transpose()) * 0.5);
        }
        for a in cases {
            let want = SymmetricEigen::new(a).eigenvalues.max();
            let got = largest_eigenvalue(&a);
            assert!((got - want).abs() <= 1e-12, "{a}: {got} vs {want}");
            assert!(gershgorin_max(&a) >= want - 1e-15);
        }
    }

    /// A tetrahedron stretched by `s` along `x` and then turned: `E_xx =
    /// ((1 + s)^2 - 1) / 2`, whatever the rotation (the measure is
    /// objective).
    #[test]
    fn a_turned_uniaxial_stretch_has_the_analytic_green_lagrange_strain() {
        let x = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.01, 0.0, 0.0),
            Point3::new(0.0, 0.01, 0.0),
            Point3::new(0.0, 0.0, 0.01),
        ];
        let mesh = TetMesh::new(x.to_vec(), vec![[0, 1, 2, 3]]).unwrap();
        let surface = BoundarySurface {
            triangles: vec![],
            to_volume: vec![],
            face_tets: vec![],
        };
        let g = InjuryGeometry::new(&mesh, &surface, &[u32::MAX; 4]);
        let rot = Rotation3::from_euler_angles(0.7, -0.3, 1.9);
        for s in [0.0, 1e-6, 0.05, 0.3, -0.4, 2.0] {
            let u: Vec<Vector3<f64>> = x
                .iter()
                .map(|p| rot * Vector3::new((1.0 + s) * p.x, p.y, p.z) - p.coords)
                .collect();
            let m = g.strain(&u, 0.1, 0, None);
            let want = ((1.0 + s) * (1.0 + s) - 1.0) / 2.0;
            let want_max = want.max(0.0);
            assert!(
                (m.max_principal - want_max).abs() <= 1e-12 * (1.0 + want.abs()),
                "s = {s}: {} vs {want_max}",
                m.max_principal
            );
            let above = if want_max >= 0.1 {
                0.01f64.powi(3) / 6.0
            } else {
                0.0
            };
            assert!((m.volume_above_m3 - above).abs() <= 1e-18, "s = {s}");
        }
    }

    /// The bound only skips: on a cube with random displacements of every
    /// size, the measure with skipping equals the one that evaluates every
    /// tetrahedron, whatever the hint.
    #[test]
    fn skipping_never_changes_the_answer() {
        let mesh = crate::mesh::blocks::cube(0.04, 5);
        let surface = BoundarySurface {
            triangles: vec![],
            to_volume: vec![],
            face_tets: vec![],
        };
        let from_volume = vec![u32::MAX; mesh.nodes.len()];
        let g = InjuryGeometry::new(&mesh, &surface, &from_volume);
        let mut next = uniform(11);
        for scale in [1e-7, 1e-4, 1e-3, 5e-3] {
            // A smooth field plus noise at a few nodes: a hot spot.
            let u: Vec<Vector3<f64>> = mesh
                .nodes
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let hot = if i % 37 == 0 {
                        3.0 * next()
                    } else {
                        0.1 * next()
                    };
                    // Plus a rigid translation, which the bound ignores.
                    Vector3::new(p.y * 10.0 + hot, p.z * 5.0 - hot, hot) * scale
                        + Vector3::new(0.01, -0.02, 0.005)
                })
                .collect();
            // Every tetrahedron evaluated.
            let (mut max, mut volume) = (f64::NEG_INFINITY, 0.0);
            for (k, t) in mesh.tets.iter().enumerate() {
                let e1 =
                    largest_eigenvalue(&green_lagrange(&g.inverse[k], t.map(|i| &u[i as usize])));
                max = max.max(e1);
                if e1 >= 0.05 {
                    volume += g.volume_m3[k];
                }
            }
            for hint in [0, 17, 123, mesh.tets.len()] {
                let fast = g.strain(&u, 0.05, hint, None);
                if max >= STRAIN_RESOLUTION {
                    assert_eq!(fast.max_principal, max, "scale {scale}, hint {hint}");
                } else {
                    assert!(
                        fast.max_principal <= max.max(0.0),
                        "scale {scale}, hint {hint}"
                    );
                }
                assert_eq!(fast.volume_above_m3, volume, "scale {scale}, hint {hint}");
            }
        }
    }

    /// A record of frames with known mean pressures: the time above and
    /// the product are the sums of the held intervals, exactly.
    #[test]
    fn a_held_pressure_record_sums_exactly() {
        let mut clock = PressureClock::default();
        let record = [
            (0.0, 0.0),
            (0.5, 3000.0),
            (1.25, 1000.0),
            (2.0, 2000.0),
            (3.0, 0.0),
        ];
        let mut last = Pressure::default();
        for (t, p) in record {
            let mut now = [Pressure {
                mean_pa: p,
                ..Default::default()
            }];
            clock.tick(t, &mut now, 2000.0);
            last = now[0];
        }
        // Held: 0 over [0, 0.5), 3000 over [0.5, 1.25), 1000 over
        // [1.25, 2), 2000 over [2, 3).
        assert_eq!(last.time_above_s, 0.75 + 1.0);
        assert_eq!(
            last.pressure_time_pa_s,
            3000.0 * 0.75 + 1000.0 * 0.75 + 2000.0
        );
    }
}
