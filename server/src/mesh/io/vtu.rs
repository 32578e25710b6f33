//! VTK XML unstructured grids (`.vtu`): reader and writer.
//!
//! The reader takes the forms VTK, ParaView and meshio write: `DataArray`s in
//! `ascii`, inline `binary` (base64) and `appended` (raw or base64) format,
//! uncompressed or zlib-compressed (`vtkZLibDataCompressor`, meshio's
//! default), with `UInt32` or `UInt64` headers, either byte order, and several
//! `Piece`s (concatenated). Cell types 10, 24 and 71 become tetrahedra of their
//! first four points; other cells are counted and skipped.
//!
//! The writer is [`fissure_shared::vtu`]'s (re-exported here): clients that
//! write frame series use it without linking the engine.

use super::cursor::show;
use super::vtk::add_cell;
use super::{ParseError, RawVolume};
use base64::Engine as _;
use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
use nalgebra::Point3;
use std::io::Read;

const B64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new()
        .with_decode_padding_mode(DecodePaddingMode::Indifferent)
        .with_decode_allow_trailing_bits(true),
);

fn perr(field: &str, message: impl Into<String>) -> ParseError {
    ParseError::file(field, message)
}

/// Element types of `DataArray`s.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "Int8" | "Char" => Self::I8,
            "UInt8" => Self::U8,
            "Int16" => Self::I16,
            "UInt16" => Self::U16,
            "Int32" => Self::I32,
            "UInt32" => Self::U32,
            "Int64" => Self::I64,
            "UInt64" => Self::U64,
            "Float32" => Self::F32,
            "Float64" => Self::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }
    fn value(self, c: &[u8], big: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let mut b = [0u8; $n];
                b.copy_from_slice(&c[..$n]);
                (if big {
                    <$t>::from_be_bytes(b)
                } else {
                    <$t>::from_le_bytes(b)
                }) as f64
            }};
        }
        match self {
            Self::I8 => c[0] as i8 as f64,
            Self::U8 => c[0] as f64,
            Self::I16 => get!(i16, 2),
            Self::U16 => get!(u16, 2),
            Self::I32 => get!(i32, 4),
            Self::U32 => get!(u32, 4),
            Self::I64 => get!(i64, 8),
            Self::U64 => get!(u64, 8),
            Self::F32 => get!(f32, 4),
            Self::F64 => get!(f64, 8),
        }
    }
}

/// File-wide settings from the `VTKFile` element and the appended block.
struct Ctx<'a> {
    big: bool,
    header: usize,
    compressed: bool,
    appended: &'a [u8],
    appended_base64: bool,
}

impl Ctx<'_> {
    fn read_header(&self, b: &[u8]) -> u64 {
        if self.header == 8 {
            let a: [u8; 8] = b[..8].try_into().unwrap_or([0; 8]);
            if self.big {
                u64::from_be_bytes(a)
            } else {
                u64::from_le_bytes(a)
            }
        } else {
            let a: [u8; 4] = b[..4].try_into().unwrap_or([0; 4]);
            (if self.big {
                u32::from_be_bytes(a)
            } else {
                u32::from_le_bytes(a)
            }) as u64
        }
    }
}

fn b64_chars(bytes: usize) -> usize {
    bytes.div_ceil(3) * 4
}

/// Decodes the first `n` bytes encoded at the start of base64 text `t`.
fn b64_prefix(t: &[u8], n: usize, field: &str) -> Result<Vec<u8>, ParseError> {
    let chars = b64_chars(n);
    if chars > t.len() {
        return Err(perr(
            field,
            format!("base64 data too short: {} bytes needed", n),
        ));
    }
    let mut v = B64
        .decode(&t[..chars])
        .map_err(|e| perr(field, format!("invalid base64: {e}")))?;
    if v.len() < n {
        return Err(perr(field, "base64 data too short"));
    }
    v.truncate(n);
    Ok(v)
}

/// The uncompressed bytes of a binary array whose encoded form starts at
/// `src` (base64 text when `base64`, else raw bytes).
fn binary_payload(
    ctx: &Ctx<'_>,
    src: &[u8],
    base64: bool,
    field: &str,
) -> Result<Vec<u8>, ParseError> {
    let h = ctx.header;
    // Upper bound of decoded bytes available, to check counts before allocating.
    let avail = if base64 {
        src.len() / 4 * 3 + 3
    } else {
        src.len()
    };
    let take = |from: usize, n: usize| -> Result<Vec<u8>, ParseError> {
        if base64 {
            b64_prefix(src.get(from..).unwrap_or_default(), n, field)
        } else {
            src.get(from..from + n)
                .map(<[u8]>::to_vec)
                .ok_or_else(|| perr(field, format!("binary data too short: {n} bytes needed")))
        }
    };
    if !ctx.compressed {
        let first = take(0, h)?;
        let n = ctx.read_header(&first);
        if n > avail as u64 {
            return Err(perr(
                field,
                format!("header says {n} bytes, only {avail} present"),
            ));
        }
        let n = n as usize;
        if !base64 {
            return take(h, n);
        }
        let hc = b64_chars(h);
        if src.get(..hc).is_some_and(|p| p.ends_with(b"=")) {
            return take(hc, n); // header and data encoded separately
        }
        let mut all = take(0, h + n)?; // encoded together
        all.drain(..h);
        return Ok(all);
    }
    let first = take(0, h)?;
    let blocks = ctx.read_header(&first);
    if blocks.saturating_mul(h as u64) > avail as u64 {
        return Err(perr(
            field,
            format!("header says {blocks} compressed blocks, too many for the data"),
        ));
    }
    let blocks = blocks as usize;
    let head = take(0, (3 + blocks) * h)?;
    let item = |k: usize| ctx.read_header(&head[k * h..(k + 1) * h]);
    let (block_size, last_size) = (item(1), item(2));
    let sizes: Vec<u64> = (0..blocks).map(|k| item(3 + k)).collect();
    let total: u64 = sizes.iter().fold(0u64, |a, &b| a.saturating_add(b));
    if total > avail as u64 {
        return Err(perr(
            field,
            format!("compressed sizes add up to {total}, more than the data"),
        ));
    }
    let data_from = if base64 {
        b64_chars((3 + blocks) * h)
    } else {
        (3 + blocks) * h
    };
    let data = if base64 {
        b64_prefix(
            src.get(data_from..).unwrap_or_default(),
            total as usize,
            field,
        )?
    } else {
        take(data_from, total as usize)?
    };
    let mut out = Vec::new();
    let mut at = 0usize;
    for (k, &c) in sizes.iter().enumerate() {
        let expect = if k + 1 == blocks && last_size != 0 {
            last_size
        } else {
            block_size
        };
        // zlib cannot expand more than about 1032:1; refuse larger claims.
        if expect > c.saturating_mul(1100).saturating_add(1024) {
            return Err(perr(
                field,
                format!("block {k} claims {expect} bytes from {c} compressed"),
            ));
        }
        let chunk = &data[at..at + c as usize];
        at += c as usize;
        let before = out.len();
        flate2::read::ZlibDecoder::new(chunk)
            .take(expect)
            .read_to_end(&mut out)
            .map_err(|e| perr(field, format!("zlib block {k}: {e}")))?;
        if (out.len() - before) as u64 != expect {
            return Err(perr(
                field,
                format!(
                    "zlib block {k} gave {} bytes, header says {expect}",
                    out.len() - before
                ),
            ));
        }
    }
    Ok(out)
}

/// Reads a `DataArray` as `f64` values, checking that it holds `count` values.
fn read_array(
    ctx: &Ctx<'_>,
    node: roxmltree::Node<'_, '_>,
    count: usize,
    field: &str,
) -> Result<Vec<f64>, ParseError> {
    let ty_name = node.attribute("type").unwrap_or("");
    let ty = Ty::parse(ty_name)
        .ok_or_else(|| perr(field, format!("DataArray type '{ty_name}' not supported")))?;
    let format = node.attribute("format").unwrap_or("ascii");
    let text = node.text().unwrap_or("");
    let bytes = match format {
        "ascii" => {
            let mut v = Vec::with_capacity(count.min(text.len() / 2 + 1));
            for tok in text.split_ascii_whitespace() {
                let x: f64 = tok.parse().map_err(|_| {
                    perr(field, format!("'{}' is not a number", show(tok.as_bytes())))
                })?;
                if !x.is_finite() {
                    return Err(perr(field, "not a finite number"));
                }
                v.push(x);
                if v.len() > count {
                    break;
                }
            }
            if v.len() != count {
                return Err(perr(field, format!("{} values, expected {count}", v.len())));
            }
            return Ok(v);
        }
        "binary" => {
            let clean: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
            binary_payload(ctx, &clean, true, field)?
        }
        "appended" => {
            let off: usize = node
                .attribute("offset")
                .and_then(|o| o.trim().parse().ok())
                .ok_or_else(|| perr(field, "appended DataArray without a valid offset"))?;
            let src = ctx
                .appended
                .get(off..)
                .ok_or_else(|| perr(field, format!("offset {off} past the appended data")))?;
            binary_payload(ctx, src, ctx.appended_base64, field)?
        }
        f => return Err(perr(field, format!("DataArray format '{f}' not supported"))),
    };
    let size = ty.size();
    if bytes.len() / size < count {
        return Err(perr(
            field,
            format!("{} values, expected {count}", bytes.len() / size),
        ));
    }
    let mut v = Vec::with_capacity(count);
    for c in bytes.chunks_exact(size).take(count) {
        let x = ty.value(c, ctx.big);
        if !x.is_finite() {
            return Err(perr(field, "not a finite number"));
        }
        v.push(x);
    }
    Ok(v)
}

fn child<'a, 'i>(n: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    n.children().find(|c| c.has_tag_name(name))
}

fn count_attr(n: roxmltree::Node<'_, '_>, name: &str, limit: usize) -> Result<usize, ParseError> {
    let v: u64 = n
        .attribute(name)
        .and_then(|s| s.trim().parse().ok())
        .ok_or_else(|| perr(name, "missing or not a count"))?;
    if v > limit as u64 {
        return Err(perr(name, format!("{v} exceeds what the file can hold")));
    }
    Ok(v as usize)
}

/// All pieces of a `.vtu` file: points and cells (flat connectivity, global
/// point indices).
struct Grid {
    points: Vec<Point3<f64>>,
    types: Vec<i64>,
    /// Cell `c` is `conn[ends[c - 1]..ends[c]]` (from 0 for the first).
    ends: Vec<usize>,
    conn: Vec<i64>,
    /// Cell data `label` per cell, when every piece has it.
    labels: Option<Vec<f64>>,
}

impl Grid {
    fn cells(&self) -> impl Iterator<Item = (usize, i64, &[i64])> {
        let starts = std::iter::once(0).chain(self.ends.iter().copied());
        starts
            .zip(&self.ends)
            .zip(&self.types)
            .enumerate()
            .map(|(c, ((a, &b), &t))| (c, t, &self.conn[a..b]))
    }
}

/// Parses a `.vtu` file into its tetrahedra.
pub fn parse(bytes: &[u8]) -> Result<RawVolume, ParseError> {
    let grid = parse_grid(bytes)?;
    let mut out = RawVolume {
        nodes: Vec::new(),
        ..Default::default()
    };
    out.nodes.clone_from(&grid.points);
    for (c, ty, ids) in grid.cells() {
        let before = out.tets.len();
        add_cell(&mut out, c, ty, ids)?;
        if let (Some(labels), true) = (&grid.labels, out.tets.len() > before) {
            let l = labels[c];
            if !(l >= 0.0 && l <= f64::from(u32::MAX) && l.fract() == 0.0) {
                return Err(perr(
                    "label",
                    format!("cell {c}: label {l} is not a non-negative integer"),
                ));
            }
            out.labels.push(l as u32);
        }
    }
    Ok(out)
}

/// Parses a `.vtu` file into its triangles (cell type 5; other cells are
/// skipped), such as [`write_vtu_surface`] writes.
pub fn parse_surface(bytes: &[u8]) -> Result<super::SurfaceMesh, ParseError> {
    let grid = parse_grid(bytes)?;
    let mut triangles = Vec::new();
    for (c, ty, ids) in grid.cells() {
        if ty == 5 {
            let mut t = [0u32; 3];
            for k in 0..3 {
                let i = *ids.get(k).ok_or_else(|| {
                    perr(
                        "connectivity",
                        format!("triangle {c} has {} points", ids.len()),
                    )
                })?;
                if i < 0 || i as usize >= grid.points.len() {
                    return Err(perr(
                        "connectivity",
                        format!("cell {c} refers to point {i}, out of range"),
                    ));
                }
                t[k] = i as u32;
            }
            triangles.push(t);
        }
    }
    Ok(super::SurfaceMesh {
        vertices: grid.points,
        triangles,
    })
}

fn parse_grid(bytes: &[u8]) -> Result<Grid, ParseError> {
    // Cut the appended block out (it may be raw binary, not text).
    let mut xml: Vec<u8>;
    let (mut appended, mut appended_base64): (&[u8], bool) = (&[], false);
    if let Some(start) = super::cursor::find(bytes, b"<AppendedData") {
        let open_end = start
            + super::cursor::find(&bytes[start..], b">")
                .ok_or_else(|| perr("AppendedData", "unterminated tag"))?;
        let tag = String::from_utf8_lossy(&bytes[start..open_end]);
        appended_base64 = tag.contains("\"base64\"");
        let us = open_end
            + super::cursor::find(&bytes[open_end..], b"_")
                .ok_or_else(|| perr("AppendedData", "no '_' before the data"))?;
        let close = bytes
            .windows(15)
            .rposition(|w| w == b"</AppendedData>")
            .filter(|&c| c > us)
            .ok_or_else(|| perr("AppendedData", "no </AppendedData>"))?;
        appended = &bytes[us + 1..close];
        xml = bytes[..us].to_vec();
        xml.extend_from_slice(&bytes[close..]);
    } else {
        xml = bytes.to_vec();
    }
    let text = std::str::from_utf8(&xml).map_err(|e| perr("XML", format!("not UTF-8: {e}")))?;
    let doc = roxmltree::Document::parse(text).map_err(|e| {
        let p = e.pos();
        ParseError {
            loc: super::Loc::Line(p.row as usize),
            field: "XML".into(),
            message: e.to_string(),
        }
    })?;
    let root = doc.root_element();
    if !root.has_tag_name("VTKFile") {
        return Err(perr("VTKFile", "the root element is not VTKFile"));
    }
    if root.attribute("type") != Some("UnstructuredGrid") {
        return Err(perr(
            "VTKFile",
            format!(
                "type '{}' not supported (UnstructuredGrid is)",
                root.attribute("type").unwrap_or("")
            ),
        ));
    }
    let compressed = match root.attribute("compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(c) => {
            return Err(perr(
                "compressor",
                format!("'{c}' not supported (vtkZLibDataCompressor is)"),
            ));
        }
    };
    let header = match root.attribute("header_type") {
        None | Some("UInt32") => 4,
        Some("UInt64") => 8,
        Some(h) => return Err(perr("header_type", format!("'{h}' not supported"))),
    };
    let big = root.attribute("byte_order") == Some("BigEndian");
    let ctx = Ctx {
        big,
        header,
        compressed,
        appended,
        appended_base64,
    };
    // No array can hold more values than bytes in the file (times the
    // largest compression ratio).
    let limit = bytes.len().saturating_mul(1100) + 1024;
    let grid =
        child(root, "UnstructuredGrid").ok_or_else(|| perr("UnstructuredGrid", "missing"))?;
    let mut out = Grid {
        points: Vec::new(),
        types: Vec::new(),
        ends: Vec::new(),
        conn: Vec::new(),
        labels: Some(Vec::new()),
    };
    let mut pieces = 0;
    let mut labelled_pieces = 0;
    for piece in grid.children().filter(|c| c.has_tag_name("Piece")) {
        pieces += 1;
        let np = count_attr(piece, "NumberOfPoints", limit)?;
        let nc = count_attr(piece, "NumberOfCells", limit)?;
        let base = out.points.len();
        let pts = child(piece, "Points")
            .and_then(|p| child(p, "DataArray"))
            .ok_or_else(|| perr("Points", "missing Points/DataArray"))?;
        let comps = pts.attribute("NumberOfComponents").unwrap_or("1");
        if comps.trim() != "3" {
            return Err(perr(
                "Points",
                format!("NumberOfComponents {comps} (expected 3)"),
            ));
        }
        let xyz = read_array(&ctx, pts, 3 * np, "Points")?;
        out.points
            .extend(xyz.chunks_exact(3).map(|c| Point3::new(c[0], c[1], c[2])));
        let cells = child(piece, "Cells").ok_or_else(|| perr("Cells", "missing"))?;
        let named = |name: &str| {
            cells
                .children()
                .find(|c| c.has_tag_name("DataArray") && c.attribute("Name") == Some(name))
                .ok_or_else(|| perr(name, "missing Cells DataArray"))
        };
        let offsets = read_array(&ctx, named("offsets")?, nc, "offsets")?;
        let types = read_array(&ctx, named("types")?, nc, "types")?;
        let total = offsets.last().copied().unwrap_or(0.0);
        if !(0.0..=limit as f64).contains(&total) {
            return Err(perr("offsets", format!("last offset {total} out of range")));
        }
        let conn = read_array(&ctx, named("connectivity")?, total as usize, "connectivity")?;
        let mut prev = 0usize;
        for c in 0..nc {
            let end = offsets[c];
            if end < prev as f64 || end > total {
                return Err(perr(
                    "offsets",
                    format!("cell {c}: offset {end} out of order"),
                ));
            }
            out.conn.extend(
                conn[prev..end as usize]
                    .iter()
                    .map(|&i| i as i64 + base as i64),
            );
            out.ends.push(out.conn.len());
            out.types.push(types[c] as i64);
            prev = end as usize;
        }
        let label = child(piece, "CellData").and_then(|d| {
            d.children()
                .find(|c| c.has_tag_name("DataArray") && c.attribute("Name") == Some("label"))
        });
        match (label, &mut out.labels) {
            (Some(a), Some(labels)) => {
                labelled_pieces += 1;
                labels.extend(read_array(&ctx, a, nc, "label")?);
            }
            _ => out.labels = None,
        }
    }
    if pieces == 0 {
        return Err(perr("Piece", "no Piece in UnstructuredGrid"));
    }
    if labelled_pieces > 0 && out.labels.is_none() {
        return Err(perr(
            "label",
            format!("cell data 'label' in {labelled_pieces} of {pieces} pieces (all or none)"),
        ));
    }
    Ok(out)
}

pub use fissure_shared::vtu::{write_vtu, write_vtu_surface};

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn round_trip_with_data() {
        let mesh = crate::mesh::blocks::cube(0.03, 2);
        let u: Vec<Vector3<f64>> = mesh.nodes.iter().map(|p| p.coords * 0.1).collect();
        let q: Vec<f64> = (0..mesh.tets.len()).map(|k| k as f64 / 7.0).collect();
        let mut buf = Vec::new();
        write_vtu(
            &mut buf,
            &mesh.nodes,
            &mesh.tets,
            &[("displacement", &u)],
            &[("quality", &q)],
        )
        .unwrap();
        let raw = parse(&buf).unwrap();
        assert_eq!(raw.nodes, mesh.nodes);
        assert_eq!(raw.tets, mesh.tets);
        // Mismatched data lengths are refused.
        let mut buf = Vec::new();
        assert!(write_vtu(&mut buf, &mesh.nodes, &mesh.tets, &[("u", &u[1..])], &[]).is_err());
    }

    #[test]
    fn tissue_labels_round_trip_as_cell_data() {
        let cube = crate::mesh::blocks::cube(0.03, 2);
        let labels: Vec<u32> = (0..cube.tets.len() as u32).map(|k| 2 + k % 3).collect();
        let mesh = cube.with_labels(labels.clone()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("labelled.vtu");
        crate::mesh::io::write_volume(&path, &mesh).unwrap();
        let back = crate::mesh::io::read_volume(&path).unwrap();
        assert_eq!(back.labels, labels);
        // A label that is not a non-negative integer is refused, by cell.
        let text = std::fs::read_to_string(&path).unwrap();
        let mut buf = Vec::new();
        let bad: Vec<f64> = (0..mesh.tets.len()).map(|k| k as f64 - 0.5).collect();
        write_vtu(&mut buf, &mesh.nodes, &mesh.tets, &[], &[("label", &bad)]).unwrap();
        let e = parse(&buf).unwrap_err().to_string();
        assert!(e.contains("cell 0") && e.contains("label"), "{e}");
        // Unlabelled files give unlabelled meshes.
        assert!(text.contains("Name=\"label\""));
        let mut buf = Vec::new();
        write_vtu(&mut buf, &mesh.nodes, &mesh.tets, &[], &[]).unwrap();
        assert!(parse(&buf).unwrap().labels.is_empty());
    }

    #[test]
    fn surface_round_trip() {
        let mesh = crate::mesh::blocks::cube(0.03, 2);
        let b = mesh.boundary();
        let mut v = Vec::new();
        b.gather(&mesh.nodes, &mut v);
        let mut buf = Vec::new();
        write_vtu_surface(&mut buf, &v, &b.triangles, &[], &[]).unwrap();
        let s = parse_surface(&buf).unwrap();
        assert_eq!(s.vertices, v);
        assert_eq!(s.triangles, b.triangles);
        // As a volume file it has no tetrahedra, only ignored cells.
        let raw = parse(&buf).unwrap();
        assert!(raw.tets.is_empty());
        assert_eq!(raw.ignored_cells, b.triangles.len());
    }

    #[test]
    fn appended_raw_data() {
        // ParaView's default layout: appended raw data, UInt32 headers.
        let pts: Vec<u8> = [0.0f64, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let conn: Vec<u8> = [0i32, 1, 2, 3]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let offs: Vec<u8> = 4i32.to_le_bytes().to_vec();
        let types = vec![10u8];
        let mut blob = Vec::new();
        let mut at = Vec::new();
        for a in [&pts, &conn, &offs, &types] {
            at.push(blob.len());
            blob.extend_from_slice(&(a.len() as u32).to_le_bytes());
            blob.extend_from_slice(a);
        }
        let mut file = format!(
            "<VTKFile type=\"UnstructuredGrid\" byte_order=\"LittleEndian\"><UnstructuredGrid><Piece NumberOfPoints=\"4\" NumberOfCells=\"1\"><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"appended\" offset=\"{}\"/></Points><Cells><DataArray type=\"Int32\" Name=\"connectivity\" format=\"appended\" offset=\"{}\"/><DataArray type=\"Int32\" Name=\"offsets\" format=\"appended\" offset=\"{}\"/><DataArray type=\"UInt8\" Name=\"types\" format=\"appended\" offset=\"{}\"/></Cells></Piece></UnstructuredGrid><AppendedData encoding=\"raw\">\n_",
            at[0], at[1], at[2], at[3]
        )
        .into_bytes();
        file.extend_from_slice(&blob);
        file.extend_from_slice(b"\n</AppendedData></VTKFile>");
        let raw = parse(&file).unwrap();
        assert_eq!(raw.tets, vec![[0, 1, 2, 3]]);
        assert_eq!(raw.nodes[3], Point3::new(0.0, 0.0, 1.0));
    }

    #[test]
    fn compressed_header_claims_are_bounded() {
        // A zlib header claiming 2^40 bytes from a few compressed bytes.
        let mut head = Vec::new();
        for x in [1u32, 1 << 30, 1 << 30, 8] {
            head.extend_from_slice(&x.to_le_bytes());
        }
        let enc = base64::engine::general_purpose::STANDARD;
        let text = format!(
            "<VTKFile type=\"UnstructuredGrid\" compressor=\"vtkZLibDataCompressor\"><UnstructuredGrid><Piece NumberOfPoints=\"1\" NumberOfCells=\"0\"><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"binary\">{}{}</DataArray></Points></Piece></UnstructuredGrid></VTKFile>",
            enc.encode(&head),
            enc.encode([0u8; 8])
        );
        let e = parse(text.as_bytes()).unwrap_err();
        assert!(
            e.message.contains("claims") || e.message.contains("more than"),
            "{e}"
        );
    }
}
