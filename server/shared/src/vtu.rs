//! VTK XML unstructured grids (`.vtu`): the writer, for tetrahedral meshes
//! and triangle surfaces with named point and cell data.
//!
//! It writes inline binary (base64, `UInt64` header, uncompressed; header and
//! data encoded together, as meshio does), `Float64` points and data, `Int64`
//! connectivity and offsets, `UInt8` types. It is called once per frame by
//! time-series writers (the watcher's surface series), so it takes plain
//! slices and a `Write`. It lives here, beside the contract, because both the
//! engine's mesh tools and clients without the engine write these files; the
//! reader is the engine's (`fissure_engine::mesh::io::vtu`).

use base64::Engine as _;
use nalgebra::{Point3, Vector3};
use std::io::Write;

/// Base64 of a `UInt64` byte count followed by the bytes (one encoding).
fn encode_block(data: &[u8]) -> String {
    let mut buf = Vec::with_capacity(8 + data.len());
    buf.extend_from_slice(&(data.len() as u64).to_le_bytes());
    buf.extend_from_slice(data);
    base64::engine::general_purpose::STANDARD.encode(buf)
}

fn data_array<W: Write>(
    w: &mut W,
    ty: &str,
    name: &str,
    comps: usize,
    data: &[u8],
) -> std::io::Result<()> {
    writeln!(
        w,
        "<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"binary\">\n{}\n</DataArray>",
        encode_block(data)
    )
}

fn bad_len(what: &str, name: &str, got: usize, want: usize) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("{what} '{name}' has {got} values for {want} entities"),
    )
}

/// Escapes a data array name for an XML attribute.
fn xml_name(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn write_grid<W: Write>(
    w: &mut W,
    points: &[Point3<f64>],
    conn: &[u32],
    per_cell: usize,
    cell_type: u8,
    point_data: &[(&str, &[Vector3<f64>])],
    cell_data: &[(&str, &[f64])],
) -> std::io::Result<()> {
    let cells = conn.len() / per_cell;
    for (name, d) in point_data {
        if d.len() != points.len() {
            return Err(bad_len("point data", name, d.len(), points.len()));
        }
    }
    for (name, d) in cell_data {
        if d.len() != cells {
            return Err(bad_len("cell data", name, d.len(), cells));
        }
    }
    if let Some(&bad) = conn.iter().find(|&&i| i as usize >= points.len()) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "a cell refers to point {bad}, but there are {} points",
                points.len()
            ),
        ));
    }
    writeln!(w, "<?xml version=\"1.0\"?>")?;
    writeln!(
        w,
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
    )?;
    writeln!(
        w,
        "<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{cells}\">",
        points.len()
    )?;
    let f64s =
        |it: &mut dyn Iterator<Item = f64>| -> Vec<u8> { it.flat_map(f64::to_le_bytes).collect() };
    writeln!(w, "<Points>")?;
    let xyz = f64s(&mut points.iter().flat_map(|p| [p.x, p.y, p.z]));
    data_array(w, "Float64", "Points", 3, &xyz)?;
    writeln!(w, "</Points>\n<Cells>")?;
    let c: Vec<u8> = conn
        .iter()
        .flat_map(|&i| (i as i64).to_le_bytes())
        .collect();
    data_array(w, "Int64", "connectivity", 1, &c)?;
    let o: Vec<u8> = (1..=cells)
        .flat_map(|k| ((k * per_cell) as i64).to_le_bytes())
        .collect();
    data_array(w, "Int64", "offsets", 1, &o)?;
    data_array(w, "UInt8", "types", 1, &vec![cell_type; cells])?;
    writeln!(w, "</Cells>")?;
    if !point_data.is_empty() {
        writeln!(w, "<PointData>")?;
        for (name, d) in point_data {
            let b = f64s(&mut d.iter().flat_map(|v| [v.x, v.y, v.z]));
            data_array(w, "Float64", &xml_name(name), 3, &b)?;
        }
        writeln!(w, "</PointData>")?;
    }
    if !cell_data.is_empty() {
        writeln!(w, "<CellData>")?;
        for (name, d) in cell_data {
            let b = f64s(&mut d.iter().copied());
            data_array(w, "Float64", &xml_name(name), 1, &b)?;
        }
        writeln!(w, "</CellData>")?;
    }
    writeln!(w, "</Piece>\n</UnstructuredGrid>\n</VTKFile>")
}

/// Writes a tetrahedral mesh as a `.vtu` (cell type 10). `point_data` are
/// named vectors per node (e.g. `("displacement", u)` in m, `("reaction",
/// f)` in N), `cell_data` named scalars per tetrahedron (e.g. a quality).
/// Every array must have one entry per node or tetrahedron, and every index
/// must be in range; otherwise an `InvalidInput` error is returned and
/// nothing is written.
pub fn write_vtu<W: Write>(
    w: &mut W,
    nodes: &[Point3<f64>],
    tets: &[[u32; 4]],
    point_data: &[(&str, &[Vector3<f64>])],
    cell_data: &[(&str, &[f64])],
) -> std::io::Result<()> {
    write_grid(w, nodes, tets.as_flattened(), 4, 10, point_data, cell_data)
}

/// Writes line segments as a `.vtu` (cell type 3, `VTK_LINE`), with the
/// same data conventions as [`write_vtu`] (`cell_data`: one value per
/// segment).
pub fn write_vtu_lines<W: Write>(
    w: &mut W,
    points: &[Point3<f64>],
    segments: &[[u32; 2]],
    point_data: &[(&str, &[Vector3<f64>])],
    cell_data: &[(&str, &[f64])],
) -> std::io::Result<()> {
    write_grid(
        w,
        points,
        segments.as_flattened(),
        2,
        3,
        point_data,
        cell_data,
    )
}

/// Writes a triangle surface as a `.vtu` (cell type 5), with the same data
/// conventions as [`write_vtu`].
pub fn write_vtu_surface<W: Write>(
    w: &mut W,
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    point_data: &[(&str, &[Vector3<f64>])],
    cell_data: &[(&str, &[f64])],
) -> std::io::Result<()> {
    write_grid(
        w,
        vertices,
        triangles.as_flattened(),
        3,
        5,
        point_data,
        cell_data,
    )
}
