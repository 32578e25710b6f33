//! Reading NIfTI images: NIfTI-1 (`n+1`, 348-byte header) and NIfTI-2
//! (`n+2`, 540-byte header) single files, gzip-compressed or not, either byte
//! order.
//!
//! * **NIfTI-1** headers are parsed by the `nifti` crate
//!   ([`::nifti::NiftiHeader::from_reader`], which also detects the byte
//!   order), and voxels are decoded by
//!   [`::nifti::NiftiType::read_primitive_value`].
//! * **NIfTI-2** headers are parsed here, by hand: the `nifti` crate (0.18)
//!   reads NIfTI-1 only. The byte order comes from `sizeof_hdr`, which is 540
//!   in the file's order. Voxels are decoded by the same `nifti` function as
//!   for NIfTI-1 (the datatype codes are shared).
//!
//! `scl_slope` and `scl_inter` are applied here, in `f64`, when the slope is
//! non-zero and finite (the crate takes them as `f32`; NIfTI-2 stores `f64`).
//!
//! Everything the header claims is checked before anything is allocated for
//! it: the dimension count (3, or 4 with `dim[4] = 1`), every dimension
//! positive, at most [`MAX_VOXELS`] voxels, `vox_offset` within the file and
//! the data present after it (for a gzip file, the data is decompressed only
//! as far as the header claims, and only as it really arrives), the datatype
//! one of the ten integer and float types. Each failure is an
//! [`ImageError`] naming the file and the field.
//!
//! The affine (voxel indices to scanner coordinates) is the sform when
//! `sform_code > 0`, else the qform when `qform_code > 0` (the quaternion
//! `b, c, d`, `a = sqrt(1 - b^2 - c^2 - d^2)`, `qfac` the sign of `pixdim[0]`
//! with 0 taken as 1, voxel sizes `pixdim[1..3]`, offsets `qoffset_x, y, z`),
//! as the NIfTI-1 standard (`nifti1.h`, method 3 then method 2) says. Method
//! 1 (no code set: voxel sizes only, no position) is refused: a mesh in the
//! wrong place would be a silent error. The chosen affine must be finite and
//! non-singular. Units come from `xyzt_units`: metres, micrometres or
//! millimetres (the default, when the code is 0 or unknown); positions are
//! converted to metres.

use ::nifti::{Endianness, NiftiHeader, NiftiType};
use nalgebra::{Matrix3, Matrix4, Vector3};
use std::io::Read;
use std::path::Path;

/// Most voxels an image may have (2^31, 16 GiB as `f64`): a header claiming
/// more is refused before anything is allocated.
pub const MAX_VOXELS: u64 = 1 << 31;

/// The name [`parse_nifti`] gives the bytes it reads, in errors.
pub const IN_MEMORY: &str = "<in memory>";

/// Which header an image was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum NiftiVersion {
    /// NIfTI-1 (`n+1`).
    One,
    /// NIfTI-2 (`n+2`).
    Two,
}

/// Where the affine came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum AffineSource {
    /// `srow_x, srow_y, srow_z` (`sform_code > 0`).
    Sform,
    /// The quaternion, `pixdim` and offsets (`qform_code > 0`, `sform_code = 0`).
    Qform,
}

impl std::fmt::Display for AffineSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Sform => "sform",
            Self::Qform => "qform",
        })
    }
}

/// A 3-D scalar image in scanner space.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Voxel values (scaled by `scl_slope`, `scl_inter`), i fastest:
    /// `values[i + dims[0] * (j + dims[1] * k)]`.
    pub values: Vec<f64>,
    /// Voxel indices `(i, j, k, 1)` to scanner coordinates, m.
    pub voxel_to_world_m: Matrix4<f64>,
    /// Where the affine came from.
    pub affine_source: AffineSource,
    /// The header's version.
    pub version: NiftiVersion,
    /// The file the image was read from ([`IN_MEMORY`] for bytes), for
    /// messages.
    pub name: String,
}

impl Image {
    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Whether the image has no voxel (never, for an image read here).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Index of voxel `(i, j, k)` in [`Image::values`].
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel sizes along i, j, k (the column norms of the affine), m.
    pub fn spacing_m(&self) -> Vector3<f64> {
        let a = self.voxel_to_world_m;
        Vector3::from_fn(|c, _| a.fixed_view::<3, 1>(0, c).norm())
    }
}

/// What is wrong with an image file; each names the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be read.
    #[error("{file}: cannot read the file")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// The gzip stream is corrupt.
    #[error("{file}: the gzip stream is corrupt: {reason}")]
    Gzip { file: String, reason: String },
    /// Too few bytes for the header.
    #[error("{file}: {len} bytes, too short for a NIfTI header (sizeof_hdr needs {need})")]
    TooShort {
        file: String,
        len: usize,
        need: usize,
    },
    /// `sizeof_hdr` is neither 348 (NIfTI-1) nor 540 (NIfTI-2), in either
    /// byte order.
    #[error("{file}: not a NIfTI file: sizeof_hdr is {value} (348 for NIfTI-1, 540 for NIfTI-2)")]
    HeaderSize { file: String, value: i32 },
    /// The magic string is wrong (or names a header/image pair).
    #[error("{file}: wrong magic {found:?} for {expected}")]
    Magic {
        file: String,
        found: String,
        expected: &'static str,
    },
    /// A dimension field is out of range.
    #[error("{file}: {field} = {value}: {reason}")]
    Dimensions {
        file: String,
        field: String,
        value: i64,
        reason: &'static str,
    },
    /// The header claims more voxels than [`MAX_VOXELS`].
    #[error("{file}: dim[1..3] = {dims:?} claims {voxels} voxels, more than the limit {limit}")]
    TooManyVoxels {
        file: String,
        dims: [i64; 3],
        voxels: u128,
        limit: u64,
    },
    /// The datatype is not one of the ten supported.
    #[error(
        "{file}: datatype = {code} is not supported (u8, i8, u16, i16, u32, i32, u64, i64, f32, f64 are)"
    )]
    DataType { file: String, code: i16 },
    /// `vox_offset` is not a usable offset.
    #[error("{file}: vox_offset = {value} is {reason}")]
    VoxOffset {
        file: String,
        value: f64,
        reason: String,
    },
    /// The voxel data ends before the header says it does.
    #[error(
        "{file}: truncated: dim and datatype need {need} bytes up to the end of the voxel data \
         (vox_offset {offset} + {voxels} voxels x {bytes_per_voxel} bytes), the file has {have}"
    )]
    Truncated {
        file: String,
        need: u64,
        have: u64,
        offset: u64,
        voxels: u64,
        bytes_per_voxel: usize,
    },
    /// Neither sform nor qform is set.
    #[error(
        "{file}: no affine: sform_code and qform_code are both 0, so the image has no position \
         in scanner space"
    )]
    NoAffine { file: String },
    /// The chosen affine is NaN, infinite or singular.
    #[error("{file}: the {field} affine is unusable: {reason}")]
    BadAffine {
        file: String,
        field: &'static str,
        reason: String,
    },
    /// The memory for the voxels could not be reserved.
    #[error("{file}: cannot allocate {bytes} bytes for the voxels")]
    OutOfMemory { file: String, bytes: u64 },
    /// The `nifti` crate refused the NIfTI-1 header.
    #[error("{file}: NIfTI-1 header: {reason}")]
    Header { file: String, reason: String },
    /// Two images to be combined differ in their grids.
    #[error("{first} and {second} differ in {what}; they must share dims and affine")]
    Mismatch {
        first: String,
        second: String,
        what: String,
    },
    /// The selection of brain voxels is invalid or selects none.
    #[error("{file}: {reason}")]
    Selection { file: String, reason: String },
    /// The mesher failed.
    #[error("meshing the image: {0}")]
    Stuffing(#[from] crate::mesh::stuffing::StuffingError),
    /// The mesh's boundary could not be made a closed manifold.
    #[error("the mesh of the image: {0}")]
    Boundary(#[from] crate::mesh::manifold::BoundaryError),
    /// The labels do not fit the mesh.
    #[error("labelling the mesh: {0}")]
    Mesh(#[from] crate::mesh::MeshError),
}

/// Reads a NIfTI-1 or NIfTI-2 file (`.nii` or `.nii.gz`; gzip is detected
/// from the content).
pub fn read_nifti(path: &Path) -> Result<Image, ImageError> {
    let file = path.display().to_string();
    crate::progress::stage(format_args!("reading {file}"));
    let bytes = std::fs::read(path).map_err(|source| ImageError::Io {
        file: file.clone(),
        source,
    })?;
    parse_named(&bytes, &file)
}

/// Parses the bytes of a NIfTI-1 or NIfTI-2 file, gzip-compressed (detected
/// from the magic bytes `1f 8b`) or not.
pub fn parse_nifti(bytes: &[u8]) -> Result<Image, ImageError> {
    parse_named(bytes, IN_MEMORY)
}

/// [`parse_nifti`], naming the bytes `file` in errors.
pub fn parse_named(bytes: &[u8], file: &str) -> Result<Image, ImageError> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        parse_stream(flate2::read::MultiGzDecoder::new(bytes), None, file)
    } else {
        parse_stream(bytes, Some(bytes.len() as u64), file)
    }
}

/// The header fields used here, from either version.
#[derive(Debug, Clone)]
struct Header {
    version: NiftiVersion,
    endianness: Endianness,
    dim: [i64; 8],
    datatype: i16,
    pixdim: [f64; 8],
    vox_offset: f64,
    scl_slope: f64,
    scl_inter: f64,
    xyzt_units: i64,
    qform_code: i64,
    sform_code: i64,
    /// quatern_b, c, d, qoffset_x, y, z.
    quatern: [f64; 6],
    srow: [[f64; 4]; 3],
}

/// Reads up to `buf.len()` bytes; returns how many (fewer only at the end).
fn read_full(r: &mut impl Read, buf: &mut [u8], file: &str) -> Result<usize, ImageError> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(stream_error(e, file)),
        }
    }
    Ok(n)
}

fn stream_error(e: std::io::Error, file: &str) -> ImageError {
    ImageError::Gzip {
        file: file.to_string(),
        reason: e.to_string(),
    }
}

/// Parses a (decompressed) stream; `total` is its length when known.
fn parse_stream(mut r: impl Read, total: Option<u64>, file: &str) -> Result<Image, ImageError> {
    let mut head = [0u8; 540];
    let got = read_full(&mut r, &mut head, file)?;
    let header = parse_header(&head[..got], file)?;
    let dims = check_dims(&header, file)?;
    let ty = data_type(header.datatype, file)?;
    let voxels = (dims[0] * dims[1] * dims[2]) as u64;
    let size = ty.size_of();
    let hdr_len = match header.version {
        NiftiVersion::One => 348u64,
        NiftiVersion::Two => 540,
    };
    let vo = header.vox_offset;
    let offset_err = |reason: String| ImageError::VoxOffset {
        file: file.to_string(),
        value: vo,
        reason,
    };
    if !vo.is_finite() || vo < hdr_len as f64 {
        return Err(offset_err(format!(
            "not an offset past the {hdr_len}-byte header"
        )));
    }
    if vo.fract() != 0.0 {
        return Err(offset_err("not a whole number of bytes".into()));
    }
    // Within the cap on voxels the data is at most 2^34 bytes; an offset
    // beyond the file (or beyond 2^40 for a stream) is refused before reading.
    let limit = total.unwrap_or(1 << 40);
    if vo > limit as f64 {
        return Err(offset_err(format!(
            "beyond the end of the file ({limit} bytes)"
        )));
    }
    let offset = vo as u64;
    let need = offset + voxels * size as u64;
    let truncated = |have: u64| ImageError::Truncated {
        file: file.to_string(),
        need,
        have,
        offset,
        voxels,
        bytes_per_voxel: size,
    };
    if let Some(total) = total
        && total < need
    {
        return Err(truncated(total));
    }
    // Skip to the voxels, then read them as far as they really arrive.
    let skip = offset.saturating_sub(got as u64);
    let mut data: Vec<u8> = Vec::new();
    if (got as u64) > offset {
        data.extend_from_slice(&head[offset as usize..got]);
    }
    let skipped = std::io::copy(&mut (&mut r).take(skip), &mut std::io::sink())
        .map_err(|e| stream_error(e, file))?;
    if skipped < skip {
        return Err(truncated(got as u64 + skipped));
    }
    let want = voxels * size as u64;
    if total.is_some() {
        // The length was checked: reserve it all at once.
        data.try_reserve_exact((want as usize).saturating_sub(data.len()))
            .map_err(|_| ImageError::OutOfMemory {
                file: file.to_string(),
                bytes: want,
            })?;
    }
    let rest = want.saturating_sub(data.len() as u64);
    (&mut r)
        .take(rest)
        .read_to_end(&mut data)
        .map_err(|e| stream_error(e, file))?;
    if (data.len() as u64) < want {
        return Err(truncated(offset + data.len() as u64));
    }
    data.truncate(want as usize);
    let affine = affine(&header, file)?;
    let values = decode(&data, ty, &header, voxels as usize, file)?;
    Ok(Image {
        dims,
        values,
        voxel_to_world_m: affine.0,
        affine_source: affine.1,
        version: header.version,
        name: file.to_string(),
    })
}

fn parse_header(head: &[u8], file: &str) -> Result<Header, ImageError> {
    if head.len() < 4 {
        return Err(ImageError::TooShort {
            file: file.to_string(),
            len: head.len(),
            need: 4,
        });
    }
    let le = i32::from_le_bytes(head[..4].try_into().unwrap_or_default());
    let be = i32::from_be_bytes(head[..4].try_into().unwrap_or_default());
    let (version, endianness) = match (le, be) {
        (348, _) => (NiftiVersion::One, Endianness::Little),
        (_, 348) => (NiftiVersion::One, Endianness::Big),
        (540, _) => (NiftiVersion::Two, Endianness::Little),
        (_, 540) => (NiftiVersion::Two, Endianness::Big),
        _ => {
            return Err(ImageError::HeaderSize {
                file: file.to_string(),
                value: le,
            });
        }
    };
    let need = match version {
        NiftiVersion::One => 348,
        NiftiVersion::Two => 540,
    };
    if head.len() < need {
        return Err(ImageError::TooShort {
            file: file.to_string(),
            len: head.len(),
            need,
        });
    }
    match version {
        NiftiVersion::One => header_1(&head[..348], endianness, file),
        NiftiVersion::Two => header_2(&head[..540], endianness, file),
    }
}

/// A NIfTI-1 header, by the `nifti` crate.
fn header_1(head: &[u8], endianness: Endianness, file: &str) -> Result<Header, ImageError> {
    // dim[0] in the byte order of sizeof_hdr: the crate guesses the order from
    // dim[0] <= 7, so check it first to name the field rightly.
    let dim0 = match endianness {
        Endianness::Little => i16::from_le_bytes([head[40], head[41]]),
        Endianness::Big => i16::from_be_bytes([head[40], head[41]]),
    };
    check_dim0(dim0 as i64, file)?;
    let magic = &head[344..348];
    if magic != b"n+1\0" {
        return Err(ImageError::Magic {
            file: file.to_string(),
            found: String::from_utf8_lossy(magic).into_owned(),
            expected: if magic == b"ni1\0" {
                "a single-file NIfTI-1 (n+1): header/image pairs (ni1, .hdr + .img) are not read"
            } else {
                "NIfTI-1 (n+1)"
            },
        });
    }
    let h = NiftiHeader::from_reader(head).map_err(|e| ImageError::Header {
        file: file.to_string(),
        reason: e.to_string(),
    })?;
    let mut dim = [0i64; 8];
    for (d, &v) in dim.iter_mut().zip(&h.dim) {
        // Stored as i16; the crate reads them as u16.
        *d = v as i16 as i64;
    }
    let f = |x: f32| x as f64;
    Ok(Header {
        version: NiftiVersion::One,
        endianness: h.endianness,
        dim,
        datatype: h.datatype,
        pixdim: h.pixdim.map(f),
        vox_offset: f(h.vox_offset),
        scl_slope: f(h.scl_slope),
        scl_inter: f(h.scl_inter),
        xyzt_units: h.xyzt_units as i64,
        qform_code: h.qform_code as i64,
        sform_code: h.sform_code as i64,
        quatern: [
            h.quatern_b,
            h.quatern_c,
            h.quatern_d,
            h.quatern_x,
            h.quatern_y,
            h.quatern_z,
        ]
        .map(f),
        srow: [h.srow_x.map(f), h.srow_y.map(f), h.srow_z.map(f)],
    })
}

/// A NIfTI-2 header (540 bytes), parsed here: see the module doc.
fn header_2(head: &[u8], endianness: Endianness, file: &str) -> Result<Header, ImageError> {
    let big = endianness == Endianness::Big;
    let b8 = |o: usize| -> [u8; 8] { head[o..o + 8].try_into().unwrap_or_default() };
    let i64_at = |o: usize| {
        if big {
            i64::from_be_bytes(b8(o))
        } else {
            i64::from_le_bytes(b8(o))
        }
    };
    let f64_at = |o: usize| {
        if big {
            f64::from_be_bytes(b8(o))
        } else {
            f64::from_le_bytes(b8(o))
        }
    };
    let i32_at = |o: usize| {
        let b: [u8; 4] = head[o..o + 4].try_into().unwrap_or_default();
        if big {
            i32::from_be_bytes(b)
        } else {
            i32::from_le_bytes(b)
        }
    };
    let i16_at = |o: usize| {
        let b = [head[o], head[o + 1]];
        if big {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    let magic = &head[4..12];
    if &magic[..4] != b"n+2\0" {
        return Err(ImageError::Magic {
            file: file.to_string(),
            found: String::from_utf8_lossy(magic).into_owned(),
            expected: if &magic[..4] == b"ni2\0" {
                "a single-file NIfTI-2 (n+2): header/image pairs (ni2) are not read"
            } else {
                "NIfTI-2 (n+2)"
            },
        });
    }
    let dim = std::array::from_fn(|k| i64_at(16 + 8 * k));
    check_dim0(dim[0], file)?;
    Ok(Header {
        version: NiftiVersion::Two,
        endianness,
        dim,
        datatype: i16_at(12),
        pixdim: std::array::from_fn(|k| f64_at(104 + 8 * k)),
        vox_offset: i64_at(168) as f64,
        scl_slope: f64_at(176),
        scl_inter: f64_at(184),
        xyzt_units: i32_at(500) as i64,
        qform_code: i32_at(344) as i64,
        sform_code: i32_at(348) as i64,
        quatern: std::array::from_fn(|k| f64_at(352 + 8 * k)),
        srow: std::array::from_fn(|r| std::array::from_fn(|c| f64_at(400 + 32 * r + 8 * c))),
    })
}

fn check_dim0(dim0: i64, file: &str) -> Result<(), ImageError> {
    if !(3..=4).contains(&dim0) {
        return Err(ImageError::Dimensions {
            file: file.to_string(),
            field: "dim[0]".into(),
            value: dim0,
            reason: "the number of dimensions must be 3 (or 4 with dim[4] = 1)",
        });
    }
    Ok(())
}

fn check_dims(h: &Header, file: &str) -> Result<[usize; 3], ImageError> {
    let bad = |k: usize, reason: &'static str| ImageError::Dimensions {
        file: file.to_string(),
        field: format!("dim[{k}]"),
        value: h.dim[k],
        reason,
    };
    check_dim0(h.dim[0], file)?;
    for k in 1..=3 {
        if h.dim[k] <= 0 {
            return Err(bad(k, "every dimension must be positive"));
        }
    }
    if h.dim[0] == 4 && h.dim[4] != 1 {
        return Err(bad(
            4,
            "a 4-D image is read only with one volume (dim[4] = 1)",
        ));
    }
    // At most (2^63)^3 < 2^190: saturate rather than overflow u128.
    let voxels = (1..=3).fold(1u128, |n, k| n.saturating_mul(h.dim[k] as u128));
    if voxels > MAX_VOXELS as u128 {
        return Err(ImageError::TooManyVoxels {
            file: file.to_string(),
            dims: [h.dim[1], h.dim[2], h.dim[3]],
            voxels,
            limit: MAX_VOXELS,
        });
    }
    Ok([h.dim[1] as usize, h.dim[2] as usize, h.dim[3] as usize])
}

fn data_type(code: i16, file: &str) -> Result<NiftiType, ImageError> {
    let h = NiftiHeader {
        datatype: code,
        ..Default::default()
    };
    let ty = h.data_type().ok();
    match ty {
        Some(
            t @ (NiftiType::Uint8
            | NiftiType::Int8
            | NiftiType::Uint16
            | NiftiType::Int16
            | NiftiType::Uint32
            | NiftiType::Int32
            | NiftiType::Uint64
            | NiftiType::Int64
            | NiftiType::Float32
            | NiftiType::Float64),
        ) => Ok(t),
        _ => Err(ImageError::DataType {
            file: file.to_string(),
            code,
        }),
    }
}

/// The factor from the header's spatial unit to metres.
fn unit_to_m(xyzt_units: i64) -> f64 {
    match xyzt_units & 0x07 {
        1 => 1.0,  // NIFTI_UNITS_METER
        3 => 1e-6, // NIFTI_UNITS_MICRON
        _ => 1e-3, // NIFTI_UNITS_MM, and the default
    }
}

/// The voxel-to-scanner affine in metres, and where it came from.
fn affine(h: &Header, file: &str) -> Result<(Matrix4<f64>, AffineSource), ImageError> {
    let bad = |field: &'static str, reason: String| ImageError::BadAffine {
        file: file.to_string(),
        field,
        reason,
    };
    let (m, source, field) = if h.sform_code > 0 {
        let s = &h.srow;
        let m = Matrix4::new(
            s[0][0], s[0][1], s[0][2], s[0][3], s[1][0], s[1][1], s[1][2], s[1][3], s[2][0],
            s[2][1], s[2][2], s[2][3], 0.0, 0.0, 0.0, 1.0,
        );
        if let Some(k) = s.iter().flatten().position(|x| !x.is_finite()) {
            return Err(bad(
                "sform",
                format!(
                    "srow_{}[{}] is {}",
                    ["x", "y", "z"][k / 4],
                    k % 4,
                    s[k / 4][k % 4]
                ),
            ));
        }
        (m, AffineSource::Sform, "sform")
    } else if h.qform_code > 0 {
        let [b, c, d, x, y, z] = h.quatern;
        if let Some(k) = h.quatern.iter().position(|x| !x.is_finite()) {
            let names = [
                "quatern_b",
                "quatern_c",
                "quatern_d",
                "qoffset_x",
                "qoffset_y",
                "qoffset_z",
            ];
            return Err(bad("qform", format!("{} is {}", names[k], h.quatern[k])));
        }
        for k in 1..=3 {
            let p = h.pixdim[k];
            if !(p.is_finite() && p > 0.0) {
                return Err(bad(
                    "qform",
                    format!("pixdim[{k}] = {p}: a voxel size must be positive"),
                ));
            }
        }
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        // As nifti1_io's nifti_quatern_to_mat44.
        let (mut b, mut c, mut d) = (b, c, d);
        let mut a = 1.0 - (b * b + c * c + d * d);
        if a < 1e-7 {
            let n = (b * b + c * c + d * d).sqrt();
            if n == 0.0 {
                return Err(bad("qform", "the quaternion is zero".into()));
            }
            (b, c, d) = (b / n, c / n, d / n);
            a = 0.0;
        } else {
            a = a.sqrt();
        }
        let r = Matrix3::new(
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - c * c - b * b,
        );
        let scale = Vector3::new(h.pixdim[1], h.pixdim[2], h.pixdim[3] * qfac);
        let lin = r * Matrix3::from_diagonal(&scale);
        let mut m = lin.to_homogeneous();
        m[(0, 3)] = x;
        m[(1, 3)] = y;
        m[(2, 3)] = z;
        (m, AffineSource::Qform, "qform")
    } else {
        return Err(ImageError::NoAffine {
            file: file.to_string(),
        });
    };
    let m = m * unit_to_m(h.xyzt_units);
    let mut m = m;
    m[(3, 3)] = 1.0;
    let lin = m.fixed_view::<3, 3>(0, 0).into_owned();
    let norms = Vector3::from_fn(|c, _| lin.column(c).norm());
    let det = lin.determinant();
    if !(det.is_finite() && norms.iter().all(|n| n.is_finite() && *n > 0.0))
        || det.abs() <= 1e-6 * norms.product()
    {
        return Err(bad(
            field,
            format!(
                "its 3x3 part is singular (determinant {det:e}, column norms {:e}, {:e}, {:e})",
                norms[0], norms[1], norms[2]
            ),
        ));
    }
    if !m.iter().all(|x| x.is_finite()) {
        return Err(bad(field, "it is not finite in metres".into()));
    }
    Ok((m, source))
}

/// Decodes the voxels to `f64` with the `nifti` crate, applying `scl_slope`
/// and `scl_inter` when the slope is non-zero and finite (a non-finite
/// intercept is taken as 0).
fn decode(
    data: &[u8],
    ty: NiftiType,
    h: &Header,
    voxels: usize,
    file: &str,
) -> Result<Vec<f64>, ImageError> {
    let (slope, inter) = if h.scl_slope.is_finite() && h.scl_slope != 0.0 {
        let inter = if h.scl_inter.is_finite() {
            h.scl_inter
        } else {
            0.0
        };
        (h.scl_slope, inter)
    } else {
        (0.0, 0.0)
    };
    let mut values: Vec<f64> = Vec::new();
    values
        .try_reserve_exact(voxels)
        .map_err(|_| ImageError::OutOfMemory {
            file: file.to_string(),
            bytes: voxels as u64 * 8,
        })?;
    let size = ty.size_of();
    // The crate rescales with f32 parameters; the f64 header values are
    // applied here, for NIfTI-2 (whose slope and intercept are f64) and
    // NIfTI-1 alike.
    for chunk in data.chunks_exact(size) {
        let raw: f64 = ty
            .read_primitive_value(chunk, h.endianness, 0.0, 0.0)
            .map_err(|e| ImageError::Header {
                file: file.to_string(),
                reason: e.to_string(),
            })?;
        values.push(if slope != 0.0 {
            raw * slope + inter
        } else {
            raw
        });
    }
    Ok(values)
}
