//! The signed distance field of a voxel mask, in scanner space.
//!
//! **Distance transform.** [`squared_edt`] is the exact Euclidean distance
//! transform of Felzenszwalb & Huttenlocher ("Distance transforms of sampled
//! functions", Theory of Computing 8, 2012): one pass along each axis of the
//! lower envelope of parabolas `s^2 (q - p)^2 + f(p)`, `s` the voxel size
//! along that axis, giving the squared distance from every voxel centre to
//! the nearest feature voxel centre in O(n). It is written here (some 40
//! lines): the Rust crate of this algorithm, `distance-transform` (0.1.2,
//! 2018), is 2-D only and unmaintained. With the affine's columns orthogonal
//! (any rotation, flip and voxel sizes) the weighted transform is the
//! Euclidean distance in scanner space; with sheared columns it is the
//! distance in the grid with the column lengths, an approximation.
//!
//! **Signed distance.** The mask is padded by one voxel of outside on every
//! side (so a shape touching the border of the image is closed there). With
//! `d_in` the distance to the nearest inside voxel centre and `d_out` the
//! distance to the nearest outside one, the grid value is
//! `+(d_in - s/2)` at an outside voxel and `-(d_out - s/2)` at an inside
//! one, `s` the smallest voxel size. Neighbouring inside and outside voxels
//! get opposite values, so the surface passes half-way between their centres
//! (along any axis, whatever the voxel sizes); for cubic voxels the values
//! are the distances to that surface along the grid axes.
//!
//! **Between voxels.** [`VoxelField`] maps a point to voxel coordinates by
//! the inverse affine and interpolates the grid trilinearly; outside the
//! (padded) grid it adds the distance to the grid box to the value at the
//! nearest box point, so the field stays positive and continuous out to
//! infinity. With cubic voxels the grid's difference between neighbours is
//! at most their distance (a slope of 1), so the trilinear field's gradient
//! is at most `sqrt(3)`, and 1 where the surface is locally flat: within the
//! factor 2 the mesher's far-cell test (`f > 2 L`) allows (see
//! [`crate::mesh::sdf`]). With voxels of sizes `s_min <= s_a`, the step
//! across the surface along axis `a` has the slope `2 - s_min / s_a`, so
//! strongly anisotropic voxels can exceed that factor right at the surface.

use crate::mesh::sdf::Sdf;
use nalgebra::{Matrix4, Point3, Vector3, Vector4};
use rayon::prelude::*;

/// In place: `f[i]` (0 at features, infinity elsewhere, or any squared
/// distances) becomes `min_p (s (i - p))^2 + f[p]`: the lower envelope of
/// parabolas, by Felzenszwalb & Huttenlocher. `v`, `z` are scratch.
fn edt_1d(f: &mut [f64], s: f64, out: &mut [f64], v: &mut Vec<usize>, z: &mut Vec<f64>) {
    let n = f.len();
    v.clear();
    z.clear();
    let x = |i: usize| i as f64 * s;
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        // Intersection of the parabola from q with the one from v.last().
        loop {
            let Some(&p) = v.last() else {
                v.push(q);
                z.push(f64::NEG_INFINITY);
                break;
            };
            let sx = ((f[q] + x(q) * x(q)) - (f[p] + x(p) * x(p))) / (2.0 * (x(q) - x(p)));
            if sx <= *z.last().unwrap_or(&f64::NEG_INFINITY) {
                v.pop();
                z.pop();
            } else {
                v.push(q);
                z.push(sx);
                break;
            }
        }
    }
    if v.is_empty() {
        out[..n].fill(f64::INFINITY);
    } else {
        let mut k = 0;
        for q in 0..n {
            while k + 1 < v.len() && z[k + 1] < x(q) {
                k += 1;
            }
            let d = x(q) - x(v[k]);
            out[q] = d * d + f[v[k]];
        }
    }
    f.copy_from_slice(&out[..n]);
}

/// The squared Euclidean distance (m^2) from every voxel centre of a grid of
/// `dims` (i fastest) with voxel sizes `spacing` (m) to the nearest voxel
/// centre where `feature` is true; infinity everywhere when there is none.
pub fn squared_edt(feature: &[bool], dims: [usize; 3], spacing: [f64; 3]) -> Vec<f64> {
    let [nx, ny, nz] = dims;
    assert_eq!(feature.len(), nx * ny * nz, "mask and dims disagree");
    let mut d: Vec<f64> = feature
        .iter()
        .map(|&b| if b { 0.0 } else { f64::INFINITY })
        .collect();
    // Along i: contiguous lines.
    d.par_chunks_mut(nx.max(1)).for_each_init(
        || (vec![0.0; nx], Vec::new(), Vec::new()),
        |(out, v, z), line| edt_1d(line, spacing[0], out, v, z),
    );
    // Along j and k: gather each line, transform, scatter; one k-slab (for
    // j) or one j-row of slabs (for k) per task.
    d.par_chunks_mut(nx * ny).for_each_init(
        || (vec![0.0; ny], vec![0.0; ny], Vec::new(), Vec::new()),
        |(line, out, v, z), slab| {
            for i in 0..nx {
                for j in 0..ny {
                    line[j] = slab[i + nx * j];
                }
                edt_1d(line, spacing[1], out, v, z);
                for j in 0..ny {
                    slab[i + nx * j] = line[j];
                }
            }
        },
    );
    let plane = nx * ny;
    let columns: Vec<Vec<f64>> = (0..plane)
        .into_par_iter()
        .map_init(
            || (vec![0.0; nz], Vec::new(), Vec::new()),
            |(out, v, z), c| {
                let mut line: Vec<f64> = (0..nz).map(|k| d[c + plane * k]).collect();
                edt_1d(&mut line, spacing[2], out, v, z);
                line
            },
        )
        .collect();
    for (c, line) in columns.into_iter().enumerate() {
        for (k, x) in line.into_iter().enumerate() {
            d[c + plane * k] = x;
        }
    }
    d
}

/// A signed distance field sampled on a voxel grid (see the module doc):
/// negative inside, m.
#[derive(Debug, Clone)]
pub struct VoxelField {
    /// Grid size (the image's plus one voxel of padding on each side).
    dims: [usize; 3],
    /// Signed distances at the voxel centres, i fastest, m.
    sd: Vec<f64>,
    /// Grid indices to scanner coordinates, m.
    voxel_to_world: Matrix4<f64>,
    /// Its inverse.
    world_to_voxel: Matrix4<f64>,
}

impl VoxelField {
    /// The field of `inside` (a mask of an image of `dims`, i fastest) whose
    /// voxel indices map to scanner space (m) by `voxel_to_world`. `None`
    /// when the affine is singular.
    pub fn new(inside: &[bool], dims: [usize; 3], voxel_to_world: &Matrix4<f64>) -> Option<Self> {
        let p = [dims[0] + 2, dims[1] + 2, dims[2] + 2];
        let mut padded = vec![false; p[0] * p[1] * p[2]];
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                let src = dims[0] * (j + dims[1] * k);
                let dst = 1 + p[0] * (j + 1 + p[1] * (k + 1));
                padded[dst..dst + dims[0]].copy_from_slice(&inside[src..src + dims[0]]);
            }
        }
        let shift = Matrix4::new_translation(&Vector3::repeat(-1.0));
        let v2w = voxel_to_world * shift;
        let w2v = v2w.try_inverse()?;
        let spacing: [f64; 3] = std::array::from_fn(|c| v2w.fixed_view::<3, 1>(0, c).norm());
        let half = 0.5 * spacing.iter().copied().fold(f64::INFINITY, f64::min);
        let d_in = squared_edt(&padded, p, spacing);
        let outside: Vec<bool> = padded.iter().map(|b| !b).collect();
        let d_out = squared_edt(&outside, p, spacing);
        let sd = padded
            .par_iter()
            .zip(d_in.par_iter().zip(d_out.par_iter()))
            .map(|(&ins, (&di, &dout))| {
                if ins {
                    -(dout.sqrt() - half)
                } else {
                    // No inside voxel at all: the field is positive everywhere.
                    if di.is_finite() {
                        di.sqrt() - half
                    } else {
                        f64::MAX.sqrt()
                    }
                }
            })
            .collect();
        Some(Self {
            dims: p,
            sd,
            voxel_to_world: v2w,
            world_to_voxel: w2v,
        })
    }

    /// The grid value at padded index `(i, j, k)`, m.
    fn at(&self, i: usize, j: usize, k: usize) -> f64 {
        self.sd[i + self.dims[0] * (j + self.dims[1] * k)]
    }

    /// The trilinear interpolation at grid coordinates `g` (inside the grid).
    fn trilinear(&self, g: [f64; 3]) -> f64 {
        let mut base = [0usize; 3];
        let mut t = [0.0; 3];
        for c in 0..3 {
            let n = self.dims[c];
            let b = (g[c].floor() as usize).min(n.saturating_sub(2));
            base[c] = b;
            t[c] = if n >= 2 { g[c] - b as f64 } else { 0.0 };
        }
        let step = |c: usize| usize::from(self.dims[c] >= 2);
        let (i0, j0, k0) = (base[0], base[1], base[2]);
        let (i1, j1, k1) = (i0 + step(0), j0 + step(1), k0 + step(2));
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let c00 = lerp(self.at(i0, j0, k0), self.at(i1, j0, k0), t[0]);
        let c10 = lerp(self.at(i0, j1, k0), self.at(i1, j1, k0), t[0]);
        let c01 = lerp(self.at(i0, j0, k1), self.at(i1, j0, k1), t[0]);
        let c11 = lerp(self.at(i0, j1, k1), self.at(i1, j1, k1), t[0]);
        lerp(lerp(c00, c10, t[1]), lerp(c01, c11, t[1]), t[2])
    }

    /// Grid (padded) coordinates of a scanner point.
    pub fn to_grid(&self, p: &Point3<f64>) -> [f64; 3] {
        let g = self.world_to_voxel * Vector4::new(p.x, p.y, p.z, 1.0);
        [g.x, g.y, g.z]
    }

    /// Scanner position of grid (padded) coordinates.
    pub fn to_world(&self, g: [f64; 3]) -> Point3<f64> {
        let w = self.voxel_to_world * Vector4::new(g[0], g[1], g[2], 1.0);
        Point3::new(w.x, w.y, w.z)
    }
}

impl Sdf for VoxelField {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let g = self.to_grid(p);
        let mut clamped = g;
        let mut out = false;
        for c in 0..3 {
            let hi = (self.dims[c] - 1) as f64;
            // NaN coordinates clamp to 0 (and the result is NaN-free).
            let x = if g[c].is_nan() { 0.0 } else { g[c] };
            clamped[c] = x.clamp(0.0, hi);
            out |= clamped[c] != g[c];
        }
        let inside = self.trilinear(clamped);
        if !out {
            return inside;
        }
        let d = Vector3::from_fn(|c, _| g[c] - clamped[c]);
        let lin = self.voxel_to_world.fixed_view::<3, 3>(0, 0);
        inside + (lin * d).norm()
    }
}
