//! Mesh file formats: readers for volume meshes (Gmsh MSH 2.2 and 4.1, VTK
//! legacy `.vtk` and XML `.vtu`, TetGen `.node`/`.ele`) and surfaces (OBJ,
//! PLY, STL), and writers (VTU for results, MSH 4.1, VTK legacy, TetGen, and
//! OBJ/PLY/STL surfaces). [`read_volume`] and [`read_surface`] pick the
//! format from the file extension.
//!
//! Volume files keep only tetrahedra: other cells (points, lines, triangles,
//! hexahedra...) are skipped and counted in [`RawVolume::ignored_cells`];
//! higher-order tetrahedra (10-node and up) keep their four corners and are
//! counted in [`RawVolume::higher_order_tets`]. [`read_volume`] then turns
//! negatively oriented tetrahedra into positive ones (a swap of two nodes; some
//! tools, TetGen among them, use the other orientation) and drops nodes used
//! by no tetrahedron (they would make the stiffness matrix singular).
//!
//! The parsers take the whole file as bytes and never panic; every count read
//! from a file is checked against the bytes that remain before anything is
//! allocated for it, so a hostile file cannot ask for more memory than its
//! own size (times a small factor). Errors name the file, the line (text) or
//! byte offset (binary), and the field that is wrong.
//!
//! The formats are written by hand rather than through a crate: no maintained
//! Rust crate reads all of them (`mshio` covers MSH 4.1 only and allocates from
//! header counts; `vtkio` pulls in a large dependency tree). XML is parsed
//! with `roxmltree`, zlib with `flate2`, base64 with `base64`.

mod cursor;
pub mod msh;
pub mod obj;
pub mod ply;
pub mod stl;
pub mod tetgen;
pub mod vtk;
pub mod vtu;

use super::{MeshError, TetMesh};
use nalgebra::Point3;
use std::fmt;
use std::path::{Path, PathBuf};

/// Where in a file a parse error is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loc {
    /// Nowhere in particular (a whole-file property).
    File,
    /// A 1-based line of a text file.
    Line(usize),
    /// A byte offset in a binary file.
    Byte(usize),
}

impl fmt::Display for Loc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Loc::File => Ok(()),
            Loc::Line(l) => write!(f, "line {l}: "),
            Loc::Byte(b) => write!(f, "byte {b}: "),
        }
    }
}

/// A format error found while parsing bytes (no path yet; [`IoError::Parse`]
/// adds it).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{loc}{field}: {message}")]
pub struct ParseError {
    /// Where the error is.
    pub loc: Loc,
    /// The field or keyword that is wrong.
    pub field: String,
    /// What is wrong with it.
    pub message: String,
}

impl ParseError {
    /// An error about the file as a whole.
    pub fn file(field: &str, message: impl Into<String>) -> Self {
        Self {
            loc: Loc::File,
            field: field.to_string(),
            message: message.into(),
        }
    }
}

/// Errors of reading or writing a mesh file; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file's content is malformed.
    #[error("{}: {source}", path.display())]
    Parse {
        path: PathBuf,
        #[source]
        source: ParseError,
    },
    /// The extension names no supported format.
    #[error("{}: unknown mesh format (extension); {expected}", path.display())]
    UnknownFormat {
        path: PathBuf,
        expected: &'static str,
    },
    /// The file holds no tetrahedra.
    #[error("{}: no tetrahedra in the file ({ignored} other cells ignored)", path.display())]
    NoTetrahedra { path: PathBuf, ignored: usize },
    /// The tetrahedra do not form a valid mesh (after fixing orientation).
    #[error("{}: {source}", path.display())]
    Mesh {
        path: PathBuf,
        #[source]
        source: MeshError,
    },
}

impl IoError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    fn parse(path: &Path, source: ParseError) -> Self {
        Self::Parse {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// A volume file as read: every node of the file (m, in file order) and its
/// tetrahedra as 0-based node indices, as oriented in the file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RawVolume {
    /// Node positions, m.
    pub nodes: Vec<Point3<f64>>,
    /// Tetrahedra (indices into `nodes`, in range), orientation as in the file.
    pub tets: Vec<[u32; 4]>,
    /// Cells that are not tetrahedra, skipped.
    pub ignored_cells: usize,
    /// Higher-order tetrahedra reduced to their four corners.
    pub higher_order_tets: usize,
    /// Tissue label per tetrahedron (parallel to `tets`; empty when the file
    /// has none): a `.vtu`'s cell data `label`.
    pub labels: Vec<u32>,
}

/// A volume file turned into a [`TetMesh`], with what was changed on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeRead {
    /// The mesh: positive tetrahedra, every node used.
    pub mesh: TetMesh,
    /// For each mesh node, its 0-based index among the file's nodes.
    pub file_nodes: Vec<u32>,
    /// Cells that are not tetrahedra, skipped.
    pub ignored_cells: usize,
    /// Higher-order tetrahedra reduced to their four corners.
    pub higher_order_tets: usize,
    /// Tetrahedra that were negatively oriented in the file and got two nodes
    /// swapped.
    pub flipped_tets: usize,
    /// File nodes used by no tetrahedron, dropped.
    pub dropped_nodes: usize,
}

/// A triangle surface: vertices (m) and triangles (0-based, in range).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SurfaceMesh {
    /// Vertex positions, m.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as vertex indices, orientation as in the file.
    pub triangles: Vec<[u32; 3]>,
}

/// Volume mesh formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VolumeFormat {
    /// Gmsh MSH 2.2 or 4.1, ASCII or binary (`.msh`).
    Msh,
    /// VTK legacy unstructured grid, ASCII or binary, version 2.x-5.1 (`.vtk`).
    Vtk,
    /// VTK XML unstructured grid (`.vtu`).
    Vtu,
    /// TetGen `.node` + `.ele` (either path names the pair).
    TetGen,
}

/// Surface mesh formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfaceFormat {
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// Stanford PLY, ASCII or binary (`.ply`).
    Ply,
    /// STL, ASCII or binary (`.stl`).
    Stl,
}

const VOLUME_EXTS: &str = "expected .msh, .vtk, .vtu, .node or .ele";
const SURFACE_EXTS: &str = "expected .obj, .ply, .stl (or a volume format: its boundary)";

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

impl VolumeFormat {
    /// The format named by a path's extension.
    pub fn from_path(path: &Path) -> Option<Self> {
        match extension(path).as_str() {
            "msh" => Some(Self::Msh),
            "vtk" => Some(Self::Vtk),
            "vtu" => Some(Self::Vtu),
            "node" | "ele" => Some(Self::TetGen),
            _ => None,
        }
    }
}

impl SurfaceFormat {
    /// The format named by a path's extension.
    pub fn from_path(path: &Path) -> Option<Self> {
        match extension(path).as_str() {
            "obj" => Some(Self::Obj),
            "ply" => Some(Self::Ply),
            "stl" => Some(Self::Stl),
            _ => None,
        }
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, IoError> {
    std::fs::read(path).map_err(|e| IoError::io(path, e))
}

/// Parses a single-file volume format from bytes (MSH, VTK, VTU). TetGen needs
/// two files: see [`tetgen::parse`].
pub fn parse_volume(bytes: &[u8], format: VolumeFormat) -> Result<RawVolume, ParseError> {
    match format {
        VolumeFormat::Msh => msh::parse(bytes),
        VolumeFormat::Vtk => vtk::parse(bytes),
        VolumeFormat::Vtu => vtu::parse(bytes),
        VolumeFormat::TetGen => Err(ParseError::file(
            "format",
            "TetGen meshes are two files; use tetgen::parse",
        )),
    }
}

/// Parses a surface format from bytes.
pub fn parse_surface(bytes: &[u8], format: SurfaceFormat) -> Result<SurfaceMesh, ParseError> {
    match format {
        SurfaceFormat::Obj => obj::parse(bytes),
        SurfaceFormat::Ply => ply::parse(bytes),
        SurfaceFormat::Stl => stl::parse(bytes),
    }
}

/// Reads a volume file as it is (no orientation fix, all nodes kept).
pub fn read_volume_raw(path: &Path) -> Result<RawVolume, IoError> {
    let format = VolumeFormat::from_path(path).ok_or_else(|| IoError::UnknownFormat {
        path: path.to_path_buf(),
        expected: VOLUME_EXTS,
    })?;
    if format == VolumeFormat::TetGen {
        let node_path = path.with_extension("node");
        let ele_path = path.with_extension("ele");
        let node = read_bytes(&node_path)?;
        let ele = read_bytes(&ele_path)?;
        return tetgen::parse(&node, &ele).map_err(|(which, e)| {
            IoError::parse(
                if which == tetgen::Which::Node {
                    &node_path
                } else {
                    &ele_path
                },
                e,
            )
        });
    }
    let bytes = read_bytes(path)?;
    parse_volume(&bytes, format).map_err(|e| IoError::parse(path, e))
}

/// Reads a volume mesh, dispatching on the extension, and returns the
/// [`TetMesh`] with a report of what was changed.
pub fn read_volume_report(path: &Path) -> Result<VolumeRead, IoError> {
    let raw = read_volume_raw(path)?;
    if raw.tets.is_empty() {
        return Err(IoError::NoTetrahedra {
            path: path.to_path_buf(),
            ignored: raw.ignored_cells,
        });
    }
    finish_volume(raw).map_err(|source| IoError::Mesh {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a volume mesh (`.msh`, `.vtk`, `.vtu`, `.node`/`.ele`): positive
/// tetrahedra, unused nodes dropped.
pub fn read_volume(path: impl AsRef<Path>) -> Result<TetMesh, IoError> {
    read_volume_report(path.as_ref()).map(|r| r.mesh)
}

/// Errors of reading the model of a scene ([`read_model`]); each names the
/// file.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    /// The file could not be read as a volume mesh.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The model is too large to be in metres.
    #[error(
        "{}: {source}: use `scale = {}` in the scene's [model] (the factor from the file's unit to metres)",
        path.display(),
        source.scale
    )]
    Units {
        path: PathBuf,
        #[source]
        source: super::units::ImplausibleSize,
    },
    /// Its boundary is not a closed manifold.
    #[error("{}: {source}", path.display())]
    Boundary {
        path: PathBuf,
        #[source]
        source: super::manifold::BoundaryError,
    },
}

/// Reads the volume mesh of a scene's model: [`read_volume`], positions
/// multiplied by `scale` (the file's unit to m), then refused when it is
/// wider than [`super::units::MAX_MODEL_EXTENT_M`] (probably millimetres) or
/// its boundary is not a closed manifold
/// ([`super::manifold::check_closed_manifold`]).
pub fn read_model(path: &Path, scale: f64) -> Result<TetMesh, ModelFileError> {
    crate::progress::stage(format_args!("reading the model {}", path.display()));
    let mut mesh = read_volume(path)?;
    super::units::scale_points(&mut mesh.nodes, scale);
    super::units::check_extent(&mesh.nodes, super::units::MAX_MODEL_EXTENT_M).map_err(
        |source| ModelFileError::Units {
            path: path.to_path_buf(),
            source,
        },
    )?;
    crate::progress::stage(format_args!(
        "checking the boundary of {} tetrahedra",
        mesh.tets.len()
    ));
    super::manifold::check_closed_manifold(&mesh).map_err(|source| ModelFileError::Boundary {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(mesh)
}

/// Orients every tetrahedron positively and drops unused nodes, then checks
/// the mesh with [`TetMesh::new`] (a degenerate tetrahedron is an error).
pub fn finish_volume(raw: RawVolume) -> Result<VolumeRead, MeshError> {
    let RawVolume {
        nodes,
        mut tets,
        ignored_cells,
        higher_order_tets,
        labels,
    } = raw;
    let mut flipped_tets = 0;
    for t in &mut tets {
        let [a, b, c, d] = t.map(|i| nodes.get(i as usize).copied().unwrap_or(Point3::origin()));
        if (b - a).cross(&(c - a)).dot(&(d - a)) < 0.0 {
            t.swap(2, 3);
            flipped_tets += 1;
        }
    }
    let file_nodes = super::drop_unused_nodes(nodes.len(), &mut tets);
    let kept: Vec<_> = file_nodes.iter().map(|&i| nodes[i as usize]).collect();
    let dropped_nodes = nodes.len() - kept.len();
    let mesh = TetMesh::new(kept, tets)?.with_labels(labels)?;
    Ok(VolumeRead {
        mesh,
        file_nodes,
        ignored_cells,
        higher_order_tets,
        flipped_tets,
        dropped_nodes,
    })
}

/// Reads a triangle surface (`.obj`, `.ply`, `.stl`); a volume format gives
/// the boundary surface of its mesh (outward triangles).
pub fn read_surface(path: impl AsRef<Path>) -> Result<SurfaceMesh, IoError> {
    let path = path.as_ref();
    if let Some(format) = SurfaceFormat::from_path(path) {
        let bytes = read_bytes(path)?;
        return parse_surface(&bytes, format).map_err(|e| IoError::parse(path, e));
    }
    if VolumeFormat::from_path(path) == Some(VolumeFormat::Vtu) {
        // A .vtu of triangles (as `write_surface` writes) is a surface.
        let bytes = read_bytes(path)?;
        let s = vtu::parse_surface(&bytes).map_err(|e| IoError::parse(path, e))?;
        if !s.triangles.is_empty() {
            return Ok(s);
        }
    }
    if VolumeFormat::from_path(path).is_some() {
        let mesh = read_volume(path)?;
        let b = mesh.boundary();
        let mut vertices = Vec::new();
        b.gather(&mesh.nodes, &mut vertices);
        return Ok(SurfaceMesh {
            vertices,
            triangles: b.triangles,
        });
    }
    Err(IoError::UnknownFormat {
        path: path.to_path_buf(),
        expected: SURFACE_EXTS,
    })
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, IoError> {
    std::fs::File::create(path)
        .map(std::io::BufWriter::new)
        .map_err(|e| IoError::io(path, e))
}

fn flush(
    path: &Path,
    w: std::io::BufWriter<std::fs::File>,
    r: std::io::Result<()>,
) -> Result<(), IoError> {
    r.and_then(|()| w.into_inner().map_err(|e| e.into_error()).map(|_| ()))
        .map_err(|e| IoError::io(path, e))
}

/// Writes a volume mesh, the format chosen by the extension: `.vtu` (binary
/// inline, with the quality and any tissue labels as cell data; only this
/// format keeps the labels), `.msh` (4.1 ASCII), `.vtk`
/// (legacy ASCII) or `.node`/`.ele` (both files, 1-based).
pub fn write_volume(path: impl AsRef<Path>, mesh: &TetMesh) -> Result<(), IoError> {
    let path = path.as_ref();
    let format = VolumeFormat::from_path(path).ok_or_else(|| IoError::UnknownFormat {
        path: path.to_path_buf(),
        expected: VOLUME_EXTS,
    })?;
    match format {
        VolumeFormat::Vtu => {
            let q = super::quality::mesh_quality(mesh);
            let rr: Vec<f64> = q.iter().map(|q| q.radius_ratio).collect();
            let dmin: Vec<f64> = q.iter().map(|q| q.min_dihedral_deg).collect();
            let labels: Vec<f64> = mesh.labels.iter().map(|&l| f64::from(l)).collect();
            let mut cell_data: Vec<(&str, &[f64])> =
                vec![("radius_ratio", &rr), ("min_dihedral_deg", &dmin)];
            if !labels.is_empty() {
                cell_data.push(("label", &labels));
            }
            let mut w = create(path)?;
            let r = vtu::write_vtu(&mut w, &mesh.nodes, &mesh.tets, &[], &cell_data);
            flush(path, w, r)
        }
        VolumeFormat::Msh => {
            let mut w = create(path)?;
            let r = msh::write_msh41(&mut w, &mesh.nodes, &mesh.tets);
            flush(path, w, r)
        }
        VolumeFormat::Vtk => {
            let mut w = create(path)?;
            let r = vtk::write_vtk(&mut w, &mesh.nodes, &mesh.tets);
            flush(path, w, r)
        }
        VolumeFormat::TetGen => {
            let node_path = path.with_extension("node");
            let ele_path = path.with_extension("ele");
            let mut w = create(&node_path)?;
            let r = tetgen::write_node(&mut w, &mesh.nodes);
            flush(&node_path, w, r)?;
            let mut w = create(&ele_path)?;
            let r = tetgen::write_ele(&mut w, &mesh.tets);
            flush(&ele_path, w, r)
        }
    }
}

/// Writes a triangle surface, the format chosen by the extension: `.obj`,
/// `.ply` (binary little endian), `.stl` (binary) or `.vtu` (cell type 5).
pub fn write_surface(
    path: impl AsRef<Path>,
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> Result<(), IoError> {
    /// The formats a surface is written in.
    enum Written {
        Obj,
        Ply,
        Stl,
        Vtu,
    }
    let path = path.as_ref();
    let format = match extension(path).as_str() {
        "obj" => Written::Obj,
        "ply" => Written::Ply,
        "stl" => Written::Stl,
        "vtu" => Written::Vtu,
        _ => {
            return Err(IoError::UnknownFormat {
                path: path.to_path_buf(),
                expected: "expected .obj, .ply, .stl or .vtu",
            });
        }
    };
    let mut w = create(path)?;
    let r = match format {
        Written::Obj => obj::write_obj(&mut w, vertices, triangles),
        Written::Ply => ply::write_ply(&mut w, vertices, triangles),
        Written::Stl => stl::write_stl(&mut w, vertices, triangles),
        Written::Vtu => vtu::write_vtu_surface(&mut w, vertices, triangles, &[], &[]),
    };
    flush(path, w, r)
}
