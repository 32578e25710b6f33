//! Tests of the NIfTI reader, the distance field and the image mesher, on
//! NIfTI files written here byte by byte (NIfTI-1 and NIfTI-2, either byte
//! order, gzip or not).

use super::*;
use crate::mesh::sdf::Sdf;
use nalgebra::{Matrix3, Matrix4, Rotation3, Unit, Vector3};
use proptest::prelude::*;
use std::f64::consts::PI;
use std::io::Write;

/// What a test file holds; [`Spec::encode`] writes it.
#[derive(Debug, Clone)]
struct Spec {
    version: u8,
    big: bool,
    dim: [i64; 8],
    datatype: i16,
    /// Voxel bytes, already in the file's byte order.
    data: Vec<u8>,
    pixdim: [f64; 8],
    /// None: right after the header (+4 extension bytes).
    vox_offset: Option<f64>,
    scl: (f64, f64),
    xyzt_units: i32,
    qform_code: i32,
    sform_code: i32,
    quatern: [f64; 6],
    srow: [[f64; 4]; 3],
}

impl Spec {
    /// A little-endian NIfTI-`version` float32 image of `values` (i fastest)
    /// with sform `affine_mm` (millimetres).
    fn f32(version: u8, dims: [usize; 3], values: &[f64], affine_mm: &Matrix4<f64>) -> Self {
        let data = values
            .iter()
            .flat_map(|&v| (v as f32).to_le_bytes())
            .collect();
        let mut srow = [[0.0; 4]; 3];
        for (r, row) in srow.iter_mut().enumerate() {
            for (c, x) in row.iter_mut().enumerate() {
                *x = affine_mm[(r, c)];
            }
        }
        let sp = |c: usize| affine_mm.fixed_view::<3, 1>(0, c).norm();
        Self {
            version,
            big: false,
            dim: [
                3,
                dims[0] as i64,
                dims[1] as i64,
                dims[2] as i64,
                1,
                1,
                1,
                1,
            ],
            datatype: 16,
            data,
            pixdim: [1.0, sp(0), sp(1), sp(2), 1.0, 1.0, 1.0, 1.0],
            vox_offset: None,
            scl: (0.0, 0.0),
            xyzt_units: 2,
            qform_code: 0,
            sform_code: 1,
            quatern: [0.0; 6],
            srow,
        }
    }

    fn header_len(&self) -> usize {
        if self.version == 1 { 348 } else { 540 }
    }

    fn encode(&self) -> Vec<u8> {
        let big = self.big;
        let mut h = vec![0u8; self.header_len()];
        let mut put = |o: usize, b: &[u8]| h[o..o + b.len()].copy_from_slice(b);
        macro_rules! bytes {
            ($x:expr) => {
                if big {
                    $x.to_be_bytes()
                } else {
                    $x.to_le_bytes()
                }
            };
        }
        let vox_offset = self.vox_offset.unwrap_or((self.header_len() + 4) as f64);
        if self.version == 1 {
            put(0, &bytes!(348i32));
            for k in 0..8 {
                put(40 + 2 * k, &bytes!(self.dim[k] as i16));
            }
            put(70, &bytes!(self.datatype));
            put(72, &bytes!(16i16));
            for k in 0..8 {
                put(76 + 4 * k, &bytes!(self.pixdim[k] as f32));
            }
            put(108, &bytes!(vox_offset as f32));
            put(112, &bytes!(self.scl.0 as f32));
            put(116, &bytes!(self.scl.1 as f32));
            put(123, &[self.xyzt_units as u8]);
            put(252, &bytes!(self.qform_code as i16));
            put(254, &bytes!(self.sform_code as i16));
            for k in 0..6 {
                put(256 + 4 * k, &bytes!(self.quatern[k] as f32));
            }
            for r in 0..3 {
                for c in 0..4 {
                    put(280 + 16 * r + 4 * c, &bytes!(self.srow[r][c] as f32));
                }
            }
            put(344, b"n+1\0");
        } else {
            put(0, &bytes!(540i32));
            put(4, b"n+2\0\r\n\x1a\n");
            put(12, &bytes!(self.datatype));
            put(14, &bytes!(16i16));
            for k in 0..8 {
                put(16 + 8 * k, &bytes!(self.dim[k]));
            }
            for k in 0..8 {
                put(104 + 8 * k, &bytes!(self.pixdim[k]));
            }
            put(168, &bytes!(vox_offset as i64));
            put(176, &bytes!(self.scl.0));
            put(184, &bytes!(self.scl.1));
            put(344, &bytes!(self.qform_code));
            put(348, &bytes!(self.sform_code));
            for k in 0..6 {
                put(352 + 8 * k, &bytes!(self.quatern[k]));
            }
            for r in 0..3 {
                for c in 0..4 {
                    put(400 + 32 * r + 8 * c, &bytes!(self.srow[r][c]));
                }
            }
            put(500, &bytes!(self.xyzt_units));
        }
        let mut out = h;
        let hl = self.header_len() as f64;
        let pad = if vox_offset.is_finite() && vox_offset > hl {
            (vox_offset as usize).min(1 << 20)
        } else {
            self.header_len() + 4
        };
        out.resize(pad, 0);
        out.extend_from_slice(&self.data);
        out
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// An affine (mm) with voxel sizes `sizes`, rotated by `angle_deg` about
/// `axis`, optionally flipping i, and translated by `offset`.
fn affine_mm(
    sizes: [f64; 3],
    axis: [f64; 3],
    angle_deg: f64,
    flip: bool,
    offset: [f64; 3],
) -> Matrix4<f64> {
    let r = Rotation3::from_axis_angle(
        &Unit::new_normalize(Vector3::from(axis)),
        angle_deg.to_radians(),
    );
    let mut s = Matrix3::from_diagonal(&Vector3::from(sizes));
    if flip {
        s[(0, 0)] = -s[(0, 0)];
    }
    let mut m = (r.matrix() * s).to_homogeneous();
    m[(0, 3)] = offset[0];
    m[(1, 3)] = offset[1];
    m[(2, 3)] = offset[2];
    // Exactly representable in NIfTI-1's float32 fields.
    m.map(|x| x as f32 as f64)
}

/// Values of a `dims` grid: `f(scanner position in mm)`.
fn sample(dims: [usize; 3], a: &Matrix4<f64>, f: impl Fn(Vector3<f64>) -> f64) -> Vec<f64> {
    let mut v = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = a * nalgebra::Vector4::new(i as f64, j as f64, k as f64, 1.0);
                v.push(f(p.xyz()));
            }
        }
    }
    v
}

const PARAMS: SurfaceMeshing = SurfaceMeshing {
    spacing: 0.002,
    levels: 1,
    rate: 0.5,
};

fn volume(m: &TetMesh) -> f64 {
    (0..m.tets.len()).map(|t| m.signed_volume(t)).sum()
}

/// The centroid of the meshed solid, m.
fn centroid(m: &TetMesh) -> Vector3<f64> {
    let mut c = Vector3::zeros();
    for (t, tet) in m.tets.iter().enumerate() {
        let g = tet
            .iter()
            .map(|&v| m.nodes[v as usize].coords)
            .sum::<Vector3<f64>>()
            / 4.0;
        c += g * m.signed_volume(t);
    }
    c / volume(m)
}

fn mesh_mask(bytes: &[u8]) -> ImageMeshed {
    let image = parse_nifti(bytes).expect("parses");
    mesh_image(&[image], &Selection::Threshold { threshold: 0.5 }, &PARAMS).expect("meshes")
}

/// Meshes a sphere mask (radius 12 mm, 1 mm-ish voxels) written with
/// `affine` and checks the laws: every tetrahedron positively oriented,
/// the boundary a closed manifold, the volume within the resolution bound,
/// the centre within a fifth of a voxel. Returns the mesh.
///
/// The bound: the mask's surface (half-way between inside and outside voxel
/// centres) is within half a voxel diagonal of the sphere but its volume
/// error averages out to well under `A s / 4` (`A = 4 pi r^2`, `s` the
/// largest voxel size); the mesh's boundary triangles are chords of that
/// surface at the spacing `h`, cutting at most `A h^2 / (8 r)`. So
/// `|V - 4/3 pi r^3| <= A (s / 4 + h^2 / (8 r))`.
fn sphere_law(affine: &Matrix4<f64>, dims: [usize; 3], version: u8) -> ImageMeshed {
    let r = 12.0;
    let centre_vox = Vector3::new(
        dims[0] as f64 * 0.5 - 0.3,
        dims[1] as f64 * 0.5 + 0.2,
        dims[2] as f64 * 0.5 + 0.45,
    );
    let centre = (affine * centre_vox.push(1.0)).xyz();
    let values = sample(dims, affine, |p| {
        f64::from(u8::from((p - centre).norm() < r))
    });
    let bytes = Spec::f32(version, dims, &values, affine).encode();
    let m = mesh_mask(&bytes);
    for t in 0..m.mesh.tets.len() {
        assert!(
            m.mesh.signed_volume(t) > 0.0,
            "tet {t} not positively oriented"
        );
    }
    assert_eq!(manifold::check_closed_manifold(&m.mesh), Ok(()));
    assert!(m.mesh.labels.iter().all(|&l| l == 1));
    let (r_m, h) = (r * 1e-3, PARAMS.spacing);
    let s = (0..3)
        .map(|c| affine.fixed_view::<3, 1>(0, c).norm())
        .fold(0.0, f64::max)
        * 1e-3;
    let exact = 4.0 / 3.0 * PI * r_m.powi(3);
    let area = 4.0 * PI * r_m * r_m;
    let bound = area * (s / 4.0 + h * h / (8.0 * r_m));
    let v = volume(&m.mesh);
    assert!(
        (v - exact).abs() <= bound,
        "volume {v:e} vs {exact:e}: error {:e} over the bound {bound:e}",
        v - exact
    );
    let c = centroid(&m.mesh);
    let off = (c - centre * 1e-3).norm();
    assert!(off < 0.2 * s, "centre off by {off:e} m (voxel {s:e} m)");
    eprintln!(
        "sphere: volume error {:.3}% (bound {:.3}%), centre off {:.4} voxel, {} tets",
        100.0 * (v / exact - 1.0),
        100.0 * bound / exact,
        off / s,
        m.mesh.tets.len()
    );
    m
}

/// Law: a sphere mask with an axis-aligned affine meshes to the sphere's
/// volume within the resolution bound, centred on the analytic centre.
#[test]
fn sphere_mask_axis_aligned() {
    let a = affine_mm(
        [1.0, 1.0, 1.0],
        [0.0, 0.0, 1.0],
        0.0,
        false,
        [-16.5, 20.0, 3.25],
    );
    sphere_law(&a, [32, 32, 32], 1);
}

/// Law: the same with an oblique affine (30 degrees about a tilted axis,
/// anisotropic voxels) and with a flipped axis (negative determinant): the
/// mesh is in scanner space, positively oriented, of the sphere's volume.
#[test]
fn sphere_mask_oblique_and_flipped() {
    let oblique = affine_mm(
        [1.0, 1.1, 0.9],
        [1.0, 2.0, 3.0],
        30.0,
        false,
        [40.0, -12.0, 7.5],
    );
    sphere_law(&oblique, [32, 30, 34], 1);
    let flipped = affine_mm(
        [1.0, 1.0, 1.0],
        [0.0, 1.0, 1.0],
        30.0,
        true,
        [-5.0, 9.0, -60.0],
    );
    assert!(flipped.fixed_view::<3, 3>(0, 0).determinant() < 0.0);
    sphere_law(&flipped, [32, 32, 32], 2);
}

/// Law: an image and its affine-equivalent copy (voxel axes permuted and
/// one flipped, the affine compensating) describe the same shape in scanner
/// space, and the lattice is anchored there: the meshes agree (same counts,
/// volume to 1e-9 relative, bounds to the mesher's root tolerance, 1e-6 of
/// the spacing: cut points are found by regula falsi to it, from a field
/// equal up to rounding).
#[test]
fn affine_equivalent_copies_give_the_same_mesh() {
    let dims = [30usize, 32, 28];
    let a = affine_mm(
        [1.0, 1.2, 0.9],
        [3.0, -1.0, 2.0],
        20.0,
        false,
        [10.0, 0.0, -30.0],
    );
    let centre = (a * Vector4::new(14.6, 15.3, 13.8, 1.0)).xyz();
    // An ellipsoid, so the permutation matters.
    let inside = |p: Vector3<f64>| {
        let q = p - centre;
        f64::from(u8::from(
            (q.x / 11.0).powi(2) + (q.y / 9.0).powi(2) + (q.z / 7.0).powi(2) < 1.0,
        ))
    };
    let values = sample(dims, &a, inside);
    // New index (i', j', k') = (k, i, n_j - 1 - j) of old (i, j, k).
    let nd = [dims[2], dims[0], dims[1]];
    let mut permuted = vec![0.0; values.len()];
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let (ip, jp, kp) = (k, i, dims[1] - 1 - j);
                permuted[ip + nd[0] * (jp + nd[1] * kp)] = values[i + dims[0] * (j + dims[1] * k)];
            }
        }
    }
    // old = P new + t: i = j', j = n_j - 1 - k', k = i'.
    let mut p = Matrix4::zeros();
    p[(0, 1)] = 1.0;
    p[(1, 2)] = -1.0;
    p[(1, 3)] = (dims[1] - 1) as f64;
    p[(2, 0)] = 1.0;
    p[(3, 3)] = 1.0;
    let a2 = a * p;
    let m1 = mesh_mask(&Spec::f32(1, dims, &values, &a).encode());
    let m2 = mesh_mask(&Spec::f32(1, nd, &permuted, &a2).encode());
    assert_eq!(m1.brain_voxels, m2.brain_voxels);
    assert_eq!(
        (m1.mesh.nodes.len(), m1.mesh.tets.len()),
        (m2.mesh.nodes.len(), m2.mesh.tets.len())
    );
    let (v1, v2) = (volume(&m1.mesh), volume(&m2.mesh));
    assert!((v1 / v2 - 1.0).abs() < 1e-9, "{v1} vs {v2}");
    let (b1, b2) = (m1.mesh.bounds(), m2.mesh.bounds());
    let tol = 1e-6 * PARAMS.spacing;
    assert!(
        (b1.0 - b2.0).amax() < tol && (b1.1 - b2.1).amax() < tol,
        "{b1:?} vs {b2:?}"
    );
}

/// Law: a cube whose halves carry labels 1 and 2 meshes to a mesh whose
/// per-label volumes are the halves' within the bound: the cube's edges
/// and corners are rounded at the spacing (at most `12 e h^2 / 2`, `e` the
/// edge length) and tetrahedra straddling the interface go to the side of
/// their centroid (at most `e^2 h / 4` either way).
#[test]
fn two_label_cube_has_its_halves() {
    let dims = [28usize, 28, 28];
    let a = affine_mm(
        [1.0, 1.0, 1.0],
        [0.0, 0.0, 1.0],
        0.0,
        false,
        [-13.5, -13.5, -13.5],
    );
    // Voxels 4..24 along each axis: a 20 mm cube (faces half-way between
    // voxel centres, at +-10 mm), label 1 for i < 14, 2 beyond: the
    // interface is the plane x = 0, a lattice plane, where tetrahedra
    // straddle it symmetrically (the labelling's tie case).
    let mut values = vec![0.0; dims[0] * dims[1] * dims[2]];
    for k in 4..24 {
        for j in 4..24 {
            for i in 4..24 {
                values[i + dims[0] * (j + dims[1] * k)] = if i < 14 { 1.0 } else { 2.0 };
            }
        }
    }
    // Decoys: labels not asked for stay outside.
    values[1 + dims[0] * (1 + dims[1])] = 3.0;
    let image = parse_nifti(&Spec::f32(1, dims, &values, &a).encode()).unwrap();
    let m = mesh_image(&[image], &Selection::Labels { labels: vec![1, 2] }, &PARAMS).unwrap();
    assert_eq!(m.brain_voxels, 8000);
    let vols = label_volumes(&m.mesh);
    assert_eq!(vols.keys().copied().collect::<Vec<_>>(), vec![1, 2]);
    let (e, h) = (0.020, PARAMS.spacing);
    let half = e * e * e / 2.0;
    let bound = 12.0 * e * h * h / 2.0 / 2.0 + e * e * h / 4.0;
    for (l, v) in &vols {
        assert!(
            (v - half).abs() <= bound,
            "label {l}: {v:e} vs {half:e} (bound {bound:e})"
        );
        eprintln!(
            "label {l}: {:.3}% (bound {:.3}%)",
            100.0 * (v / half - 1.0),
            100.0 * bound / half
        );
    }
    // Every tetrahedron's label is the side of the interface (x = 0) its
    // centroid is on, away from the interface.
    for (t, tet) in m.mesh.tets.iter().enumerate() {
        let x = tet.iter().map(|&v| m.mesh.nodes[v as usize].x).sum::<f64>() / 4.0;
        if x.abs() > 0.5e-3 {
            assert_eq!(
                m.mesh.labels[t],
                if x < 0.0 { 1 } else { 2 },
                "tet {t} at x = {x}"
            );
        }
    }
}

/// Law: two smooth probability maps thresholded at 0.5 (their sum) with
/// labels by argmax give exactly the mesh of the label map made from them
/// by the same rule (same nodes, tetrahedra and labels).
#[test]
fn probability_maps_reproduce_their_label_map() {
    let dims = [30usize, 30, 30];
    let a = affine_mm(
        [1.0, 1.0, 1.0],
        [1.0, 1.0, 0.0],
        15.0,
        false,
        [-15.0, -15.0, -15.0],
    );
    let sigmoid = |x: f64| 1.0 / (1.0 + (-x).exp());
    // "Grey": a shell around "white": a ball.
    let white = sample(dims, &a, |p| {
        sigmoid((8.0 - (p - Vector3::new(1.0, 0.5, 0.0)).norm()) * 1.5)
    });
    let grey = sample(dims, &a, |p| {
        let r = p.norm();
        sigmoid((12.0 - r) * 1.5)
            * (1.0 - sigmoid((8.0 - (p - Vector3::new(1.0, 0.5, 0.0)).norm()) * 1.5))
    });
    let labels: Vec<f64> = grey
        .iter()
        .zip(&white)
        .map(|(&g, &w)| {
            let (g, w) = (g as f32 as f64, w as f32 as f64);
            if g + w > 0.5 {
                if w > g { 2.0 } else { 1.0 }
            } else {
                0.0
            }
        })
        .collect();
    assert!(labels.contains(&1.0) && labels.contains(&2.0));
    let g = parse_nifti(&Spec::f32(1, dims, &grey, &a).encode()).unwrap();
    let w = parse_nifti(&Spec::f32(2, dims, &white, &a).encode()).unwrap();
    let l = parse_nifti(&gzip(&Spec::f32(1, dims, &labels, &a).encode())).unwrap();
    let from_maps = mesh_image(&[g, w], &Selection::Threshold { threshold: 0.5 }, &PARAMS).unwrap();
    let from_labels = mesh_image(&[l], &Selection::Labels { labels: vec![1, 2] }, &PARAMS).unwrap();
    assert_eq!(from_maps.brain_voxels, from_labels.brain_voxels);
    assert_eq!(from_maps.mesh, from_labels.mesh);
    let vols = label_volumes(&from_maps.mesh);
    assert_eq!(vols.len(), 2, "{vols:?}");
}

/// Law: the two versions, byte orders and compressions of the same data
/// read to the same image, and NIfTI-1 and NIfTI-2 mesh to the same mesh.
#[test]
fn versions_byte_orders_and_gzip_agree() {
    let dims = [20usize, 22, 18];
    let a = affine_mm(
        [1.0, 1.0, 1.5],
        [0.2, 1.0, 0.3],
        40.0,
        true,
        [3.0, -7.0, 11.0],
    );
    let c = (a * Vector4::new(9.5, 11.0, 8.5, 1.0)).xyz();
    let values = sample(dims, &a, |p| f64::from(u8::from((p - c).norm() < 7.0)));
    let s1 = Spec::f32(1, dims, &values, &a);
    let s2 = Spec::f32(2, dims, &values, &a);
    let mut s1_be = s1.clone();
    s1_be.big = true;
    s1_be.data = values
        .iter()
        .flat_map(|&v| (v as f32).to_be_bytes())
        .collect();
    let mut s2_be = s2.clone();
    s2_be.big = true;
    s2_be.data = s1_be.data.clone();
    let base = parse_nifti(&s1.encode()).unwrap();
    assert_eq!(base.values, values);
    assert_eq!(base.version, NiftiVersion::One);
    assert_eq!(base.affine_source, AffineSource::Sform);
    let want = a.fixed_view::<3, 4>(0, 0) * 1e-3;
    assert!((base.voxel_to_world_m.fixed_view::<3, 4>(0, 0) - want).amax() < 1e-15);
    for (what, bytes) in [
        ("nifti-2", s2.encode()),
        ("nifti-1 big-endian", s1_be.encode()),
        ("nifti-2 big-endian", s2_be.encode()),
        ("nifti-1 gzip", gzip(&s1.encode())),
        ("nifti-2 big-endian gzip", gzip(&s2_be.encode())),
    ] {
        let im = parse_nifti(&bytes).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(
            (&im.values, im.dims, im.voxel_to_world_m),
            (&base.values, base.dims, base.voxel_to_world_m),
            "{what}"
        );
    }
    let m1 = mesh_mask(&s1.encode());
    let m2 = mesh_mask(&gzip(&s2.encode()));
    assert_eq!(m1.mesh, m2.mesh);
}

/// Law: the ten datatypes decode to the stored values times `scl_slope`
/// plus `scl_inter` (when the slope is non-zero and finite), in both byte
/// orders and versions; units m and um scale the affine.
#[test]
fn datatypes_scaling_and_units() {
    let raw: [f64; 6] = [0.0, 1.0, 2.0, 7.0, 100.0, 120.0];
    let a = affine_mm([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0, false, [0.0; 3]);
    for version in [1u8, 2] {
        for big in [false, true] {
            for (code, size) in [
                (2i16, 1usize),
                (256, 1),
                (4, 2),
                (512, 2),
                (8, 4),
                (768, 4),
                (1024, 8),
                (1280, 8),
                (16, 4),
                (64, 8),
            ] {
                let mut s = Spec::f32(version, [3, 2, 1], &raw, &a);
                s.big = big;
                s.datatype = code;
                macro_rules! enc {
                    ($t:ty) => {
                        raw.iter()
                            .flat_map(|&v| {
                                let x = v as $t;
                                if big {
                                    x.to_be_bytes().to_vec()
                                } else {
                                    x.to_le_bytes().to_vec()
                                }
                            })
                            .collect::<Vec<u8>>()
                    };
                }
                s.data = match code {
                    2 => enc!(u8),
                    256 => enc!(i8),
                    4 => enc!(i16),
                    512 => enc!(u16),
                    8 => enc!(i32),
                    768 => enc!(u32),
                    1024 => enc!(i64),
                    1280 => enc!(u64),
                    16 => enc!(f32),
                    _ => enc!(f64),
                };
                assert_eq!(s.data.len(), raw.len() * size);
                let what = format!("v{version} big {big} datatype {code}");
                let im = parse_nifti(&s.encode()).unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_eq!(im.values, raw, "{what}");
                s.scl = (0.5, -3.0);
                let im = parse_nifti(&s.encode()).unwrap();
                let want: Vec<f64> = raw.iter().map(|v| v * 0.5 - 3.0).collect();
                assert_eq!(im.values, want, "{what} scaled");
                s.scl = (f64::NAN, 9.0);
                assert_eq!(
                    parse_nifti(&s.encode()).unwrap().values,
                    raw,
                    "{what} NaN slope"
                );
            }
        }
    }
    let mut s = Spec::f32(1, [3, 2, 1], &raw, &a);
    s.xyzt_units = 1; // metres
    assert_eq!(
        parse_nifti(&s.encode()).unwrap().voxel_to_world_m[(0, 0)],
        1.0
    );
    s.xyzt_units = 3 | 8; // micrometres, seconds
    assert_eq!(
        parse_nifti(&s.encode()).unwrap().voxel_to_world_m[(0, 0)],
        1e-6
    );
    s.xyzt_units = 0; // unknown: millimetres
    assert_eq!(
        parse_nifti(&s.encode()).unwrap().voxel_to_world_m[(0, 0)],
        1e-3
    );
}

/// Law: the qform (quaternion, pixdim, qfac, offsets) gives the rotation
/// it encodes, and is used only when the sform code is 0; a 4-D image with
/// one volume reads as 3-D.
#[test]
fn qform_and_4d_with_one_volume() {
    let a = affine_mm(
        [1.0, 1.5, 2.0],
        [1.0, -2.0, 0.5],
        70.0,
        true,
        [4.0, 5.0, 6.0],
    );
    let values = vec![0.0; 24];
    let mut s = Spec::f32(2, [2, 3, 4], &values, &a);
    // The quaternion of the rotation part (the flip goes into qfac = -1 on k:
    // rebuild as R diag(sizes) diag(1, 1, -1) with R proper).
    let lin = a.fixed_view::<3, 3>(0, 0).into_owned();
    let sizes = Vector3::new(1.0, 1.5, 2.0);
    let mut r = lin * Matrix3::from_diagonal(&sizes.map(|x| 1.0 / x));
    r.set_column(2, &(-r.column(2)));
    let q = nalgebra::UnitQuaternion::from_matrix(&r);
    let q = if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    };
    s.sform_code = 0;
    s.qform_code = 1;
    s.pixdim = [-1.0, 1.0, 1.5, 2.0, 1.0, 1.0, 1.0, 1.0];
    s.quatern = [q.i, q.j, q.k, 4.0, 5.0, 6.0];
    s.srow = [[f64::NAN; 4]; 3]; // ignored
    let want = {
        let mut m = (r * Matrix3::from_diagonal(&Vector3::new(1.0, 1.5, -2.0))).to_homogeneous();
        m[(0, 3)] = 4.0;
        m[(1, 3)] = 5.0;
        m[(2, 3)] = 6.0;
        m * 1e-3
    };
    let im = parse_nifti(&s.encode()).unwrap();
    assert_eq!(im.affine_source, AffineSource::Qform);
    let got = im.voxel_to_world_m;
    assert!(
        (got.fixed_view::<3, 4>(0, 0) - want.fixed_view::<3, 4>(0, 0)).amax() < 1e-9,
        "{got} vs {want}"
    );
    s.dim[0] = 4;
    s.dim[4] = 1;
    assert_eq!(parse_nifti(&s.encode()).unwrap().dims, [2, 3, 4]);
}

/// The variant and the message's field of a bad file's error.
fn err_of(bytes: &[u8]) -> ImageError {
    match parse_nifti(bytes) {
        Ok(im) => panic!("accepted: {:?}", im.dims),
        Err(e) => e,
    }
}

/// Law: every malformed file is a typed error naming the field (and the
/// file), before any allocation for what the header claims.
#[test]
fn malformed_files_are_typed_errors_naming_the_field() {
    let a = affine_mm([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0, false, [0.0; 3]);
    let values = vec![1.0; 4 * 4 * 4];
    for version in [1u8, 2] {
        let good = Spec::f32(version, [4, 4, 4], &values, &a);
        let v = format!("NIfTI-{version}");
        // Wrong magic.
        let mut b = good.encode();
        let at = if version == 1 { 344 } else { 4 };
        b[at..at + 3].copy_from_slice(b"xyz");
        let e = err_of(&b);
        assert!(matches!(e, ImageError::Magic { .. }), "{v}: {e}");
        assert!(e.to_string().contains("magic"), "{e}");
        // Not a header at all.
        let e = err_of(b"\x01\x02\x03\x04 and some more bytes");
        assert!(
            matches!(e, ImageError::HeaderSize { value, .. } if value == 0x04030201),
            "{e}"
        );
        assert!(e.to_string().contains("sizeof_hdr"), "{e}");
        // Too short for the header.
        let e = err_of(&good.encode()[..200]);
        assert!(
            matches!(e, ImageError::TooShort { len: 200, .. }),
            "{v}: {e}"
        );
        // Truncated data.
        let full = good.encode();
        let e = err_of(&full[..full.len() - 5]);
        assert!(matches!(e, ImageError::Truncated { .. }), "{v}: {e}");
        assert!(
            e.to_string().contains("truncated") && e.to_string().contains("vox_offset"),
            "{e}"
        );
        // Truncated gzip stream.
        let gz = gzip(&full);
        let e = err_of(&gz[..gz.len() / 2]);
        assert!(
            matches!(e, ImageError::Truncated { .. } | ImageError::Gzip { .. }),
            "{v}: {e}"
        );
        // Corrupt gzip stream.
        let mut gz = gz.clone();
        for x in &mut gz[12..40] {
            *x ^= 0x5a;
        }
        let e = err_of(&gz);
        assert!(
            matches!(
                e,
                ImageError::Gzip { .. }
                    | ImageError::HeaderSize { .. }
                    | ImageError::TooShort { .. }
            ),
            "{v}: {e}"
        );
        // 2-D and 5-D.
        for d0 in [2, 5, 0, -3] {
            let mut s = good.clone();
            s.dim[0] = d0;
            let e = err_of(&s.encode());
            assert!(
                matches!(&e, ImageError::Dimensions { field, value, .. } if field == "dim[0]" && *value == d0),
                "{v} dim[0] = {d0}: {e}"
            );
            assert!(e.to_string().contains("dim[0]"), "{e}");
        }
        // 4-D with several volumes.
        let mut s = good.clone();
        s.dim[0] = 4;
        s.dim[4] = 2;
        let e = err_of(&s.encode());
        assert!(
            matches!(&e, ImageError::Dimensions { field, .. } if field == "dim[4]"),
            "{v}: {e}"
        );
        // Zero and negative dimensions.
        for (k, d) in [(1usize, 0i64), (2, -4), (3, 0)] {
            let mut s = good.clone();
            s.dim[k] = d;
            let e = err_of(&s.encode());
            let want = format!("dim[{k}]");
            assert!(
                matches!(&e, ImageError::Dimensions { field, .. } if *field == want),
                "{v}: {e}"
            );
            assert!(e.to_string().contains(&want), "{e}");
        }
        // NaN and singular affines.
        let mut s = good.clone();
        s.srow[1][2] = f64::NAN;
        let e = err_of(&s.encode());
        assert!(
            matches!(&e, ImageError::BadAffine { field: "sform", .. }),
            "{v}: {e}"
        );
        assert!(e.to_string().contains("srow_y[2]"), "{e}");
        let mut s = good.clone();
        s.srow[2] = [1.0, 1.0, 0.0, 0.0];
        s.srow[0] = [1.0, 1.0, 0.0, 0.0];
        let e = err_of(&s.encode());
        assert!(
            matches!(&e, ImageError::BadAffine { field: "sform", .. }),
            "{v}: {e}"
        );
        assert!(e.to_string().contains("singular"), "{e}");
        let mut s = good.clone();
        s.sform_code = 0;
        s.qform_code = 1;
        s.pixdim[2] = 0.0;
        let e = err_of(&s.encode());
        assert!(e.to_string().contains("pixdim[2]"), "{v}: {e}");
        let mut s = good.clone();
        s.sform_code = 0;
        s.qform_code = 2;
        s.quatern[4] = f64::INFINITY;
        let e = err_of(&s.encode());
        assert!(e.to_string().contains("qoffset_y"), "{v}: {e}");
        // No affine.
        let mut s = good.clone();
        s.sform_code = 0;
        s.qform_code = 0;
        let e = err_of(&s.encode());
        assert!(matches!(e, ImageError::NoAffine { .. }), "{v}: {e}");
        assert!(e.to_string().contains("sform_code and qform_code"), "{e}");
        // Unsupported datatype (complex64).
        let mut s = good.clone();
        s.datatype = 32;
        let e = err_of(&s.encode());
        assert!(
            matches!(e, ImageError::DataType { code: 32, .. }),
            "{v}: {e}"
        );
        assert!(e.to_string().contains("datatype"), "{e}");
        // A huge header: 30000^3 voxels in a 400-byte file (plain and gzip).
        let mut s = good.clone();
        s.dim[1..4].copy_from_slice(&[30000, 30000, 30000]);
        let mut b = s.encode();
        b.truncate(400.max(s.header_len() + 4));
        for b in [b.clone(), gzip(&b)] {
            let e = err_of(&b);
            assert!(matches!(e, ImageError::TooManyVoxels { .. }), "{v}: {e}");
            assert!(e.to_string().contains("dim[1..3]"), "{e}");
        }
        // Dimensions whose product overflows 128 bits (NIfTI-2's are i64).
        if version == 2 {
            let mut s = good.clone();
            s.dim[1..4].copy_from_slice(&[1 << 62, 1 << 62, 1 << 62]);
            let e = err_of(&s.encode());
            assert!(matches!(e, ImageError::TooManyVoxels { .. }), "{v}: {e}");
        }
        // Within the cap but more than the file holds: truncated, before
        // reading (plain) or as the stream ends (gzip).
        let mut s = good.clone();
        s.dim[1..4].copy_from_slice(&[1000, 1000, 1000]);
        for b in [s.encode(), gzip(&s.encode())] {
            let e = err_of(&b);
            assert!(matches!(e, ImageError::Truncated { .. }), "{v}: {e}");
        }
        // Huge, negative, fractional and NaN vox_offset.
        for off in [1e12, 3.0e9, -8.0, 352.5, f64::NAN] {
            if version == 2 && (off.is_nan() || off.fract() != 0.0) {
                continue; // an integer field in NIfTI-2
            }
            let mut s = good.clone();
            s.vox_offset = Some(off);
            let mut b = s.encode();
            if off > 1e6 {
                b.extend_from_slice(&good.data);
            }
            let e = err_of(&b);
            assert!(matches!(e, ImageError::VoxOffset { .. }), "{v} {off}: {e}");
            assert!(e.to_string().contains("vox_offset"), "{e}");
        }
    }
    // A header/image pair is named as such.
    let mut b = Spec::f32(1, [4, 4, 4], &values, &a).encode();
    b[344..348].copy_from_slice(b"ni1\0");
    assert!(err_of(&b).to_string().contains("header/image pairs"));
    // The file name is in the message.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.nii");
    std::fs::write(&path, b"not a nifti file at all").unwrap();
    let e = read_nifti(&path).unwrap_err();
    assert!(e.to_string().contains("broken.nii"), "{e}");
}

/// Law: selections that select nothing, maps that disagree in grid, and
/// labels with several maps are errors naming both files.
/// The fuzz seeds (`server/fuzz/make_seeds.py`, written with Python's
/// `struct`, not this crate) are read as nibabel reads them: shape, voxel
/// sum and affine (nibabel's figures, printed when the seeds were made).
#[test]
fn the_fuzz_seeds_read_as_nibabel_reads_them() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/nifti");
    type Seed = (&'static str, [usize; 3], f64, [[f64; 4]; 3]);
    let expect: [Seed; 5] = [
        (
            "ball-1.nii",
            [8, 8, 8],
            81.0,
            [
                [1.0, 0.0, 0.0, -4.0],
                [0.0, 1.0, 0.0, -4.0],
                [0.0, 0.0, 1.0, -4.0],
            ],
        ),
        (
            "ball-1-qform-f32-big.nii",
            [6, 7, 5],
            36.0,
            [
                [1.0, 0.0, 0.0, -4.0],
                [0.0, 1.0, 0.0, -4.0],
                [0.0, 0.0, 1.0, -4.0],
            ],
        ),
        (
            "ball-1-oblique.nii.gz",
            [8, 8, 8],
            81.0,
            [
                [0.866, -0.5, 0.0, -3.0],
                [0.5, 0.866, 0.0, -5.0],
                [0.0, 0.0, -1.0, 4.0],
            ],
        ),
        (
            "ball-2.nii",
            [8, 8, 8],
            81.0,
            [
                [1.0, 0.0, 0.0, -4.0],
                [0.0, 1.0, 0.0, -4.0],
                [0.0, 0.0, 1.0, -4.0],
            ],
        ),
        (
            "ball-2-qform-f32.nii.gz",
            [5, 6, 7],
            20.0,
            [
                [1.0, 0.0, 0.0, -4.0],
                [0.0, 1.0, 0.0, -4.0],
                [0.0, 0.0, 1.0, -4.0],
            ],
        ),
    ];
    for (name, dims, sum, affine_mm) in expect {
        let image = read_nifti(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(image.dims, dims, "{name}");
        assert_eq!(image.values.iter().sum::<f64>(), sum, "{name}");
        for r in 0..3 {
            for c in 0..4 {
                let got = image.voxel_to_world_m[(r, c)] * 1e3;
                assert!(
                    (got - affine_mm[r][c]).abs() < 1e-3,
                    "{name}: affine ({r}, {c}) {got}"
                );
            }
        }
    }
}

#[test]
fn selection_errors() {
    let a = affine_mm([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0, false, [0.0; 3]);
    let values = vec![0.2; 64];
    let mut one = parse_nifti(&Spec::f32(1, [4, 4, 4], &values, &a).encode()).unwrap();
    one.name = "grey.nii".into();
    let e = mesh_image(
        &[one.clone()],
        &Selection::Threshold { threshold: 0.5 },
        &PARAMS,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("no voxel is above the threshold 0.5"),
        "{e}"
    );
    let mut moved = one.clone();
    moved.name = "white.nii".into();
    moved.voxel_to_world_m[(1, 3)] += 1e-6;
    let e = brain_labels(
        &[one.clone(), moved.clone()],
        &Selection::Threshold { threshold: 0.5 },
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("grey.nii") && msg.contains("white.nii") && msg.contains("affine"),
        "{msg}"
    );
    // Within 1e-6 of a voxel: the same grid.
    moved.voxel_to_world_m[(1, 3)] = one.voxel_to_world_m[(1, 3)] + 1e-10;
    assert!(
        brain_labels(
            &[one.clone(), moved.clone()],
            &Selection::Threshold { threshold: 0.5 }
        )
        .is_ok()
    );
    let e = brain_labels(
        &[one.clone(), moved],
        &Selection::Labels { labels: vec![1] },
    )
    .unwrap_err();
    assert!(e.to_string().contains("one label map"), "{e}");
    let e = brain_labels(&[one], &Selection::Labels { labels: vec![0, 2] }).unwrap_err();
    assert!(e.to_string().contains("0 is background"), "{e}");
}

/// Law: the distance transform is exact: against brute force on a random
/// anisotropic grid.
#[test]
fn distance_transform_matches_brute_force() {
    let dims = [7usize, 5, 6];
    let spacing = [0.7, 1.3, 1.0];
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let feature: Vec<bool> = (0..dims[0] * dims[1] * dims[2])
        .map(|_| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % 9 == 0
        })
        .collect();
    let d = field::squared_edt(&feature, dims, spacing);
    let pos = |n: usize| {
        let (i, j, k) = (n % dims[0], n / dims[0] % dims[1], n / (dims[0] * dims[1]));
        Vector3::new(
            i as f64 * spacing[0],
            j as f64 * spacing[1],
            k as f64 * spacing[2],
        )
    };
    for n in 0..feature.len() {
        let want = (0..feature.len())
            .filter(|&m| feature[m])
            .map(|m| (pos(n) - pos(m)).norm_squared())
            .fold(f64::INFINITY, f64::min);
        assert!((d[n] - want).abs() < 1e-12, "voxel {n}: {} vs {want}", d[n]);
    }
    assert!(
        field::squared_edt(&[false; 8], [2, 2, 2], [1.0; 3])
            .iter()
            .all(|x| x.is_infinite())
    );
}

/// Law: the field is negative exactly at inside voxel centres, zero
/// half-way between neighbouring inside and outside centres, and a
/// distance bound: its change between random points is at most sqrt(3)
/// times their distance, inside the grid and outside it.
#[test]
fn field_sign_surface_and_lipschitz() {
    let dims = [12usize, 10, 11];
    let a = affine_mm(
        [1.0, 1.0, 1.0],
        [1.0, 2.0, 2.0],
        25.0,
        true,
        [5.0, -3.0, 2.0],
    ) * 1e-3;
    let mut a = a;
    a[(3, 3)] = 1.0;
    let inside: Vec<bool> = (0..dims[0] * dims[1] * dims[2])
        .map(|n| {
            let (i, j, k) = (n % dims[0], n / dims[0] % dims[1], n / (dims[0] * dims[1]));
            (i as f64 - 5.0).powi(2) + (j as f64 - 4.5).powi(2) + (k as f64 - 5.2).powi(2) < 12.0
        })
        .collect();
    let f = field::VoxelField::new(&inside, dims, &a).unwrap();
    let world = |g: [f64; 3]| {
        let w = a * Vector4::new(g[0], g[1], g[2], 1.0);
        nalgebra::Point3::new(w.x, w.y, w.z)
    };
    for n in 0..inside.len() {
        let g = [
            (n % dims[0]) as f64,
            (n / dims[0] % dims[1]) as f64,
            (n / (dims[0] * dims[1])) as f64,
        ];
        let d = f.distance(&world(g));
        assert_eq!(d < 0.0, inside[n], "voxel {n}: {d}");
        // Half-way to an outside neighbour along i: zero.
        if inside[n] && n % dims[0] + 1 < dims[0] && !inside[n + 1] {
            let mid = f.distance(&world([g[0] + 0.5, g[1], g[2]]));
            assert!(mid.abs() < 1e-15, "{mid}");
        }
    }
    let mut seed = 0x1234_5678_9abc_def1u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..5000 {
        let p = world([rnd() * 16.0 - 2.0, rnd() * 14.0 - 2.0, rnd() * 15.0 - 2.0]);
        let q = p + Vector3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 0.004;
        let (fp, fq) = (f.distance(&p), f.distance(&q));
        assert!(
            (fp - fq).abs() <= 3f64.sqrt() * (p - q).norm() * (1.0 + 1e-9),
            "{fp} {fq}"
        );
    }
    // Far outside: positive and growing like the distance.
    let far = f.distance(&world([100.0, 5.0, 5.0]));
    assert!(far > 0.08 && far < 0.1, "{far}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// Law: any bytes give an image or a typed error, never a panic.
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1200)) {
        let _ = parse_nifti(&bytes);
    }

    /// Law: a valid file with random header bytes changed (and maybe cut
    /// short, maybe gzip-compressed) gives an image or a typed error, never a
    /// panic; an image read has as many values as its dims say.
    #[test]
    fn mutated_headers_never_panic(
        version in 1u8..=2,
        big in any::<bool>(),
        edits in proptest::collection::vec((0usize..540, any::<u8>()), 1..8),
        cut in proptest::option::of(0usize..1200),
        gz in any::<bool>(),
    ) {
        let a = affine_mm([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], 0.0, false, [0.0; 3]);
        let mut s = Spec::f32(version, [5, 4, 3], &vec![1.0; 60], &a);
        s.big = big;
        let mut b = s.encode();
        for (at, x) in edits {
            if at < s.header_len() {
                b[at] = x;
            }
        }
        if let Some(n) = cut {
            b.truncate(n);
        }
        if gz {
            b = gzip(&b);
        }
        if let Ok(im) = parse_nifti(&b) {
            prop_assert_eq!(im.values.len(), im.dims.iter().product::<usize>());
        }
    }
}

use nalgebra::Vector4;
