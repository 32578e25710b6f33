//! Meshing a patient's brain from an image: a segmentation of an MRI scan,
//! read from NIfTI files ([`nifti`]), made a signed distance field in
//! scanner space ([`field`]) and meshed by isosurface stuffing.
//!
//! # What is brain
//! [`Selection`] says which voxels are brain:
//! * [`Selection::Threshold`]: the voxelwise sum of one or more maps is
//!   above the threshold. One binary mask with threshold 0.5 is the mask
//!   (`value > 0.5`); probability maps (grey and white matter, say) are
//!   summed, and must share dims and affine.
//! * [`Selection::Labels`]: one integer label map; the voxels whose value
//!   (rounded) is one of the labels.
//!
//! # Method
//! 1. The inside mask is made a signed distance field on the voxel grid in
//!    metres (exact Euclidean distance transform, surface half-way between
//!    inside and outside voxel centres), interpolated trilinearly between
//!    voxel centres through the inverse affine ([`field::VoxelField`]).
//!    Oblique and flipped affines need nothing special: the field is a
//!    function of scanner position.
//! 2. The field is meshed by [`stuffing::stuff_proven`](crate::mesh::stuffing::stuff_proven) (surface at the
//!    spacing everywhere, interior graded, dihedral angles within the proven
//!    bounds) on a lattice anchored at the scanner origin: the mesh depends
//!    on the shape in scanner space only, not on how the voxels are stored.
//! 3. The boundary is made a closed manifold by
//!    [`manifold::repair_boundary`] (sulci narrower than the spacing pinch
//!    it), and the repair is reported; pieces apart from the largest
//!    (islands of brain voxels) are dropped and counted, since nothing
//!    would hold them.
//! 4. Each tetrahedron gets a tissue label ([`TetMesh::labels`]): the
//!    label of the voxel nearest its centroid (a centroid half-way between
//!    voxel centres goes to the side a hash of the node indices picks); when that voxel is not brain
//!    (the centroid is in the half voxel the surface adds), the most common
//!    label among the brain voxels of the 26 around it, then in growing cubic
//!    shells up to [`MAX_LABEL_SEARCH`] voxels away (ties to the smaller
//!    label), and past that the image's most common brain label. A voxel's
//!    label is: for a label map, its value; for one threshold map, 1; for
//!    several, 1 + the index of the map with the largest value there (grey
//!    matter given first and white second: grey 1, white 2).
//!
//! The spacing's default in `fissure mesh from-image` is 2 mm: twice the
//! usual 1 mm voxel, so the surface follows the segmentation's gyri at the
//! scale the voxels resolve them without a tetrahedron per voxel; sulci
//! narrower than it close or pinch (repaired).

pub mod field;
pub mod nifti;

pub use self::nifti::{
    AffineSource, IN_MEMORY, Image, ImageError, MAX_VOXELS, NiftiVersion, parse_named, parse_nifti,
    read_nifti,
};

use super::TetMesh;
pub use super::from_surface::SurfaceMeshing;
use super::manifold::{self, BoundaryRepair};
use super::sdf::Aabb;
use field::VoxelField;
use nalgebra::{Matrix4, Point3, Vector4};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// How far (in voxels) the label of a tetrahedron whose nearest voxel is
/// not brain is looked for before the image's most common label is used.
pub const MAX_LABEL_SEARCH: usize = 8;

/// Which voxels are brain.
#[derive(Debug, Clone, PartialEq)]
pub enum Selection {
    /// The voxelwise sum of the images is above `threshold`.
    Threshold { threshold: f64 },
    /// One label map: voxels whose rounded value is one of `labels`.
    Labels { labels: Vec<u32> },
}

/// A meshed image and what was noticed on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageMeshed {
    /// The tetrahedral mesh, m, with a tissue label per tetrahedron; its
    /// boundary is a closed manifold.
    pub mesh: TetMesh,
    /// How its boundary was repaired (empty when it needed nothing).
    pub repair: BoundaryRepair,
    /// Pieces apart from the largest (islands of brain voxels), dropped:
    /// nothing would hold them.
    pub dropped_pieces: usize,
    /// Their tetrahedra.
    pub dropped_tets: usize,
    /// Voxels selected as brain.
    pub brain_voxels: usize,
    /// Their volume (voxel count times voxel volume), m^3.
    pub brain_voxel_volume_m3: f64,
}

/// The inside mask of `images` under `selection` (i fastest), and each
/// voxel's label (0 where not brain). The images must share dims and
/// affine.
pub fn brain_labels(images: &[Image], selection: &Selection) -> Result<Vec<u32>, ImageError> {
    let Some(first) = images.first() else {
        return Err(ImageError::Selection {
            file: String::new(),
            reason: "no image given".into(),
        });
    };
    check_same_grid(images)?;
    let labels = match selection {
        Selection::Threshold { threshold } => {
            if !threshold.is_finite() {
                return Err(ImageError::Selection {
                    file: first.name.clone(),
                    reason: format!("the threshold {threshold} is not a finite number"),
                });
            }
            (0..first.len())
                .into_par_iter()
                .map(|v| {
                    let (mut sum, mut best, mut best_k) = (0.0, f64::NEG_INFINITY, 0);
                    for (k, im) in images.iter().enumerate() {
                        let x = im.values[v];
                        sum += x;
                        if x > best {
                            (best, best_k) = (x, k);
                        }
                    }
                    if sum > *threshold {
                        best_k as u32 + 1
                    } else {
                        0
                    }
                })
                .collect()
        }
        Selection::Labels { labels } => {
            if images.len() != 1 {
                return Err(ImageError::Selection {
                    file: images[1].name.clone(),
                    reason: format!(
                        "brain labels select from one label map, {} images given",
                        images.len()
                    ),
                });
            }
            if labels.is_empty() || labels.contains(&0) {
                return Err(ImageError::Selection {
                    file: first.name.clone(),
                    reason: "give the brain labels, positive integers (0 is background)".into(),
                });
            }
            first
                .values
                .par_iter()
                .map(|&x| {
                    let r = x.round();
                    if r >= 1.0 && r <= u32::MAX as f64 && labels.contains(&(r as u32)) {
                        r as u32
                    } else {
                        0
                    }
                })
                .collect()
        }
    };
    Ok(labels)
}

/// Checks that all images have the first one's dims and affine (entries
/// within 1e-6 of the largest voxel size).
fn check_same_grid(images: &[Image]) -> Result<(), ImageError> {
    let first = &images[0];
    let tol = 1e-6 * first.spacing_m().max();
    for im in &images[1..] {
        let what = if im.dims != first.dims {
            Some(format!("dims ({:?} and {:?})", first.dims, im.dims))
        } else {
            let diff = (im.voxel_to_world_m - first.voxel_to_world_m).amax();
            (diff > tol || diff.is_nan()).then(|| {
                format!("affine (entries differ by up to {diff:e} m, more than {tol:e} m)")
            })
        };
        if let Some(what) = what {
            return Err(ImageError::Mismatch {
                first: first.name.clone(),
                second: im.name.clone(),
                what,
            });
        }
    }
    Ok(())
}

/// Meshes the brain of `images` (see the module doc).
pub fn mesh_image(
    images: &[Image],
    selection: &Selection,
    params: &SurfaceMeshing,
) -> Result<ImageMeshed, ImageError> {
    let labels = brain_labels(images, selection)?;
    let first = &images[0];
    let inside: Vec<bool> = labels.par_iter().map(|&l| l > 0).collect();
    let brain_voxels = inside.iter().filter(|&&b| b).count();
    if brain_voxels == 0 {
        return Err(ImageError::Selection {
            file: first.name.clone(),
            reason: match selection {
                Selection::Threshold { threshold } => {
                    format!("no voxel is above the threshold {threshold}")
                }
                Selection::Labels { labels } => format!("no voxel has a label in {labels:?}"),
            },
        });
    }
    let a = first.voxel_to_world_m;
    let voxel_volume = a.fixed_view::<3, 3>(0, 0).determinant().abs();
    crate::progress::stage(format_args!(
        "distance transform of {} x {} x {} voxels ({brain_voxels} brain)",
        first.dims[0], first.dims[1], first.dims[2]
    ));
    let field = VoxelField::new(&inside, first.dims, &a).ok_or_else(|| ImageError::BadAffine {
        file: first.name.clone(),
        field: "voxel_to_world",
        reason: "not invertible".into(),
    })?;
    let bounds = brain_bounds(&inside, first.dims, &a);
    crate::progress::stage(format_args!(
        "meshing the brain: isosurface stuffing at {} m",
        params.spacing
    ));
    let mesh = params.stuff(&field, Point3::origin(), bounds)?;
    crate::progress::stage(format_args!(
        "labelling and checking the boundary of {} tetrahedra",
        mesh.tets.len()
    ));
    let tet_labels = label_tets(&mesh, &labels, first.dims, &a);
    let mesh = mesh.with_labels(tet_labels)?;
    let (mesh, repair) = manifold::repair_boundary(mesh)?;
    // Islands of brain voxels apart from the brain (and pieces the repair
    // cut off) would float: only the largest piece is kept.
    let (mesh, dropped_pieces, dropped_tets) = super::adjacency::largest_component(mesh)?;
    Ok(ImageMeshed {
        mesh,
        repair,
        dropped_pieces,
        dropped_tets,
        brain_voxels,
        brain_voxel_volume_m3: brain_voxels as f64 * voxel_volume,
    })
}

/// The scanner-space box of the brain voxels, grown by one voxel.
fn brain_bounds(inside: &[bool], dims: [usize; 3], a: &Matrix4<f64>) -> Aabb {
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            let row = dims[0] * (j + dims[1] * k);
            for i in 0..dims[0] {
                if inside[row + i] {
                    for (c, x) in [i, j, k].into_iter().enumerate() {
                        lo[c] = lo[c].min(x);
                        hi[c] = hi[c].max(x);
                    }
                }
            }
        }
    }
    let mut b_lo = Point3::from(nalgebra::Vector3::repeat(f64::INFINITY));
    let mut b_hi = Point3::from(nalgebra::Vector3::repeat(f64::NEG_INFINITY));
    for corner in 0..8 {
        let g: [f64; 3] = std::array::from_fn(|c| {
            if corner >> c & 1 == 0 {
                lo[c] as f64 - 1.0
            } else {
                hi[c] as f64 + 1.0
            }
        });
        let w = a * Vector4::new(g[0], g[1], g[2], 1.0);
        let p = Point3::new(w.x, w.y, w.z);
        b_lo = b_lo.inf(&p);
        b_hi = b_hi.sup(&p);
    }
    Aabb { lo: b_lo, hi: b_hi }
}

/// The label of each tetrahedron (see the module doc): `labels` per voxel
/// (0 where not brain).
fn label_tets(mesh: &TetMesh, labels: &[u32], dims: [usize; 3], a: &Matrix4<f64>) -> Vec<u32> {
    let w2v = a.try_inverse().unwrap_or_else(Matrix4::identity);
    // The image's most common brain label: the last resort.
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for &l in labels.iter().filter(|&&l| l > 0) {
        *counts.entry(l).or_default() += 1;
    }
    let fallback = most_common(&counts).unwrap_or(1);
    let at = |i: i64, j: i64, k: i64| -> u32 {
        if i < 0 || j < 0 || k < 0 {
            return 0;
        }
        let (i, j, k) = (i as usize, j as usize, k as usize);
        if i >= dims[0] || j >= dims[1] || k >= dims[2] {
            return 0;
        }
        labels[i + dims[0] * (j + dims[1] * k)]
    };
    mesh.tets
        .par_iter()
        .map(|t| {
            let c = t
                .iter()
                .map(|&v| mesh.nodes[v as usize].coords)
                .sum::<nalgebra::Vector3<f64>>()
                / 4.0;
            let g = w2v * Vector4::new(c.x, c.y, c.z, 1.0);
            // On a tie (the centroid half-way between voxel centres, as when
            // a voxel face is a lattice plane and tetrahedra straddle it
            // symmetrically) the side is a hash bit of the node indices:
            // neither side is favoured.
            let hash = t.iter().fold(0x9e37_79b9_7f4a_7c15u64, |h, &v| {
                let mut x = (h ^ u64::from(v)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                x ^= x >> 31;
                x.wrapping_mul(0x94d0_49bb_1331_11eb)
            });
            let [i, j, k] = [0, 1, 2].map(|a| {
                let x = g[a];
                let r = if (x - x.floor() - 0.5).abs() < 1e-9 {
                    if hash >> (40 + a) & 1 == 0 {
                        x.floor()
                    } else {
                        x.ceil()
                    }
                } else {
                    x.round()
                };
                r.clamp(-1e9, 1e9) as i64
            });
            let own = at(i, j, k);
            if own > 0 {
                return own;
            }
            for r in 1..=MAX_LABEL_SEARCH as i64 {
                let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
                for dk in -r..=r {
                    for dj in -r..=r {
                        for di in -r..=r {
                            if di.abs().max(dj.abs()).max(dk.abs()) != r {
                                continue;
                            }
                            let l = at(i + di, j + dj, k + dk);
                            if l > 0 {
                                *counts.entry(l).or_default() += 1;
                            }
                        }
                    }
                }
                if let Some(l) = most_common(&counts) {
                    return l;
                }
            }
            fallback
        })
        .collect()
}

/// The key with the largest count, the smallest such key on ties.
fn most_common(counts: &BTreeMap<u32, usize>) -> Option<u32> {
    counts
        .iter()
        .fold(None, |best: Option<(u32, usize)>, (&l, &n)| match best {
            Some((_, bn)) if bn >= n => best,
            _ => Some((l, n)),
        })
        .map(|(l, _)| l)
}

/// Volume of each tissue label of a mesh (label 0 for a mesh without
/// labels), m^3, by label.
pub fn label_volumes(mesh: &TetMesh) -> BTreeMap<u32, f64> {
    let mut out = BTreeMap::new();
    for t in 0..mesh.tets.len() {
        *out.entry(mesh.label(t)).or_insert(0.0) += mesh.signed_volume(t);
    }
    out
}

#[cfg(test)]
mod tests;
