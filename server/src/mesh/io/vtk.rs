//! VTK legacy files (`.vtk`): `DATASET UNSTRUCTURED_GRID`, ASCII or BINARY
//! (big endian), with the classic `CELLS n size` list (versions 2.0-4.2) or
//! the `OFFSETS`/`CONNECTIVITY` arrays of version 5.1 (meshio's default).
//!
//! Cells of type 10 (tetra), 24 (quadratic tetra) and 71 (Lagrange tetra)
//! become tetrahedra of their first four points; other cell types are counted
//! and skipped. Point and cell data are not read.

use super::cursor::{Cursor, show};
use super::{ParseError, RawVolume};
use nalgebra::Point3;
use std::io::Write;

/// Bytes of one value of a legacy data type in binary files.
fn type_size(t: &[u8]) -> Option<usize> {
    Some(match t {
        b"bit" | b"unsigned_char" | b"char" => 1,
        b"unsigned_short" | b"short" => 2,
        b"unsigned_int" | b"int" | b"float" | b"vtkIdType" => 4,
        b"unsigned_long" | b"long" | b"double" | b"vtktypeint64" | b"vtktypeuint64" => 8,
        _ => return None,
    })
}

fn is_float(t: &[u8]) -> bool {
    t == b"float" || t == b"double"
}

/// Reads `n` values of type `ty` as `f64` (ASCII tokens or big-endian binary).
fn read_values(
    cur: &mut Cursor<'_>,
    binary: bool,
    ty: &[u8],
    n: usize,
    field: &str,
    out: &mut Vec<f64>,
) -> Result<(), ParseError> {
    let size = type_size(ty)
        .ok_or_else(|| cur.err(field, format!("data type '{}' not supported", show(ty))))?;
    let n = cur.check_count(n as u64, if binary { size } else { 2 }, field)?;
    out.reserve(n);
    if !binary {
        for _ in 0..n {
            out.push(cur.f64(field)?);
        }
        return Ok(());
    }
    cur.binary = true;
    let bytes = cur.take(n * size, field)?;
    cur.binary = false;
    for c in bytes.chunks_exact(size) {
        let v = match (ty, size) {
            (b"float", _) => f32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
            (b"double", _) => f64::from_be_bytes(c.try_into().unwrap_or([0; 8])),
            (b"char", 1) => c[0] as i8 as f64,
            (_, 1) => c[0] as f64,
            (b"short", 2) => i16::from_be_bytes([c[0], c[1]]) as f64,
            (_, 2) => u16::from_be_bytes([c[0], c[1]]) as f64,
            (b"unsigned_int", 4) => u32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
            (_, 4) => i32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
            (b"unsigned_long" | b"vtktypeuint64", _) => {
                u64::from_be_bytes(c.try_into().unwrap_or([0; 8])) as f64
            }
            _ => i64::from_be_bytes(c.try_into().unwrap_or([0; 8])) as f64,
        };
        if !v.is_finite() {
            return Err(cur.err(field, "not a finite number"));
        }
        out.push(v);
    }
    Ok(())
}

/// Reads `n` integer values (indices, counts, types).
fn read_ints(
    cur: &mut Cursor<'_>,
    binary: bool,
    ty: &[u8],
    n: usize,
    field: &str,
    out: &mut Vec<i64>,
) -> Result<(), ParseError> {
    if is_float(ty) {
        return Err(cur.err(
            field,
            format!("integer data expected, found type '{}'", show(ty)),
        ));
    }
    if !binary {
        let n = cur.check_count(n as u64, 2, field)?;
        out.reserve(n);
        for _ in 0..n {
            out.push(cur.parse(field)?);
        }
        return Ok(());
    }
    let mut tmp = Vec::new();
    read_values(cur, binary, ty, n, field, &mut tmp)?;
    out.extend(tmp.into_iter().map(|v| v as i64));
    Ok(())
}

/// Skips a `FIELD name n` block and its arrays.
fn skip_field(cur: &mut Cursor<'_>, binary: bool) -> Result<(), ParseError> {
    let _name = cur.token();
    let arrays: u64 = cur.parse("FIELD numArrays")?;
    let arrays = cur.check_count(arrays, 8, "FIELD numArrays")?;
    let mut sink = Vec::new();
    for _ in 0..arrays {
        let _array = cur.token();
        let comps: u64 = cur.parse("FIELD numComponents")?;
        let tuples: u64 = cur.parse("FIELD numTuples")?;
        let ty = cur
            .token()
            .ok_or_else(|| cur.err("FIELD dataType", "missing"))?;
        let n = comps.saturating_mul(tuples);
        let n = cur.check_count(n, 1, "FIELD values")?;
        if binary {
            cur.skip_to_line_start();
        }
        sink.clear();
        read_values(cur, binary, ty, n, "FIELD values", &mut sink)?;
        skip_metadata(cur);
    }
    Ok(())
}

/// Skips an optional `METADATA` block (ends at an empty line).
fn skip_metadata(cur: &mut Cursor<'_>) {
    let save = (cur.pos, cur.line);
    if cur.token() != Some(b"METADATA") {
        (cur.pos, cur.line) = save;
        return;
    }
    cur.line_bytes();
    while let Some(l) = cur.line_bytes() {
        if l.iter().all(|b| b.is_ascii_whitespace()) {
            break;
        }
    }
}

impl Cursor<'_> {
    /// Moves to the start of the next line (after a keyword line, before
    /// binary data).
    fn skip_to_line_start(&mut self) {
        while let Some(&b) = self.data.get(self.pos) {
            self.pos += 1;
            if b == b'\n' {
                self.line += 1;
                break;
            }
        }
    }
}

/// Parses a legacy VTK unstructured grid.
pub fn parse(bytes: &[u8]) -> Result<RawVolume, ParseError> {
    let mut cur = Cursor::new(bytes);
    let header = cur.line_bytes().unwrap_or_default();
    if !header.starts_with(b"# vtk DataFile") {
        return Err(ParseError {
            loc: super::Loc::Line(1),
            field: "header".into(),
            message: "expected '# vtk DataFile Version ...'".into(),
        });
    }
    cur.line_bytes(); // title
    let binary = match cur.token() {
        Some(b"ASCII") => false,
        Some(b"BINARY") => true,
        other => {
            return Err(cur.err(
                "file type",
                format!(
                    "expected ASCII or BINARY, found '{}'",
                    show(other.unwrap_or_default())
                ),
            ));
        }
    };
    let mut points: Option<Vec<f64>> = None;
    let mut cells: Option<Cells> = None;
    let mut types: Option<Vec<i64>> = None;
    let mut dataset = false;
    while let Some(tok) = cur.token() {
        match tok {
            b"DATASET" => {
                let kind = cur.token().unwrap_or_default();
                if kind != b"UNSTRUCTURED_GRID" {
                    return Err(cur.err(
                        "DATASET",
                        format!("'{}' not supported (UNSTRUCTURED_GRID is)", show(kind)),
                    ));
                }
                dataset = true;
            }
            b"FIELD" => skip_field(&mut cur, binary)?,
            b"METADATA" => {
                cur.line_bytes();
                while let Some(l) = cur.line_bytes() {
                    if l.iter().all(|b| b.is_ascii_whitespace()) {
                        break;
                    }
                }
            }
            b"POINTS" => {
                let n: u64 = cur.parse("POINTS count")?;
                let ty = cur
                    .token()
                    .ok_or_else(|| cur.err("POINTS dataType", "missing"))?;
                let n = cur.check_count(n, 3, "POINTS count")?;
                if binary {
                    cur.skip_to_line_start();
                }
                let mut v = Vec::new();
                read_values(&mut cur, binary, ty, 3 * n, "POINTS", &mut v)?;
                points = Some(v);
            }
            b"CELLS" => {
                let a: u64 = cur.parse("CELLS count")?;
                let b: u64 = cur.parse("CELLS size")?;
                let save = (cur.pos, cur.line);
                if cur.token() == Some(b"OFFSETS") {
                    let ty = cur
                        .token()
                        .ok_or_else(|| cur.err("OFFSETS dataType", "missing"))?;
                    let a = cur.check_count(a, 1, "CELLS count")?;
                    if binary {
                        cur.skip_to_line_start();
                    }
                    let mut offsets = Vec::new();
                    read_ints(&mut cur, binary, ty, a, "OFFSETS", &mut offsets)?;
                    cur.expect("CONNECTIVITY")?;
                    let ty = cur
                        .token()
                        .ok_or_else(|| cur.err("CONNECTIVITY dataType", "missing"))?;
                    let b = cur.check_count(b, 1, "CELLS size")?;
                    if binary {
                        cur.skip_to_line_start();
                    }
                    let mut conn = Vec::new();
                    read_ints(&mut cur, binary, ty, b, "CONNECTIVITY", &mut conn)?;
                    cells = Some(Cells::Offsets { offsets, conn });
                } else {
                    (cur.pos, cur.line) = save;
                    let b = cur.check_count(b, 1, "CELLS size")?;
                    if binary {
                        cur.skip_to_line_start();
                    }
                    let mut list = Vec::new();
                    read_ints(&mut cur, binary, b"int", b, "CELLS", &mut list)?;
                    cells = Some(Cells::Legacy { count: a, list });
                }
                skip_metadata(&mut cur);
            }
            b"CELL_TYPES" => {
                let n: u64 = cur.parse("CELL_TYPES count")?;
                let n = cur.check_count(n, 1, "CELL_TYPES count")?;
                if binary {
                    cur.skip_to_line_start();
                }
                let mut t = Vec::new();
                read_ints(&mut cur, binary, b"int", n, "CELL_TYPES", &mut t)?;
                types = Some(t);
            }
            b"POINT_DATA" | b"CELL_DATA" => break,
            t => {
                return Err(cur.err("keyword", format!("unexpected '{}'", show(t))));
            }
        }
    }
    if !dataset {
        return Err(ParseError::file(
            "DATASET",
            "no DATASET UNSTRUCTURED_GRID line",
        ));
    }
    let points = points.ok_or_else(|| ParseError::file("POINTS", "no POINTS section"))?;
    let cells = cells.unwrap_or(Cells::Legacy {
        count: 0,
        list: Vec::new(),
    });
    let types = types.unwrap_or_default();
    let nodes: Vec<Point3<f64>> = points
        .chunks_exact(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect();
    let mut out = RawVolume {
        nodes,
        ..Default::default()
    };
    let cell_lists = split_cells(&cells)?;
    if cell_lists.len() != types.len() {
        return Err(ParseError::file(
            "CELL_TYPES",
            format!("{} cell types for {} cells", types.len(), cell_lists.len()),
        ));
    }
    for (cell, (ids, &ty)) in cell_lists.iter().zip(&types).enumerate() {
        add_cell(&mut out, cell, ty, ids)?;
    }
    Ok(out)
}

/// The two forms of the cell arrays.
enum Cells {
    /// `CELLS n size`: for each cell its point count, then its points.
    Legacy { count: u64, list: Vec<i64> },
    /// Version 5.1: `OFFSETS` (cells + 1 entries) into `CONNECTIVITY`.
    Offsets { offsets: Vec<i64>, conn: Vec<i64> },
}

/// Splits either form of the cell arrays into per-cell index slices.
fn split_cells(cells: &Cells) -> Result<Vec<&[i64]>, ParseError> {
    let mut out = Vec::new();
    match cells {
        Cells::Legacy { count, list } => {
            let mut i = 0;
            while i < list.len() {
                let n = list[i];
                if n < 0 || n as usize > list.len() - i - 1 {
                    return Err(ParseError::file(
                        "CELLS",
                        format!("cell {} has bad size {n}", out.len()),
                    ));
                }
                out.push(&list[i + 1..i + 1 + n as usize]);
                i += 1 + n as usize;
            }
            if out.len() as u64 != *count {
                return Err(ParseError::file(
                    "CELLS",
                    format!("{count} cells declared, {} found", out.len()),
                ));
            }
        }
        Cells::Offsets { offsets, conn } => {
            for w in offsets.windows(2) {
                let (a, b) = (w[0], w[1]);
                if a < 0 || b < a || b as usize > conn.len() {
                    return Err(ParseError::file("OFFSETS", format!("bad offsets {a}..{b}")));
                }
                out.push(&conn[a as usize..b as usize]);
            }
        }
    }
    Ok(out)
}

/// Adds cell `cell` of VTK type `ty` to `out`: tetrahedra kept (corners),
/// other cells counted.
pub(crate) fn add_cell(
    out: &mut RawVolume,
    cell: usize,
    ty: i64,
    ids: &[i64],
) -> Result<(), ParseError> {
    let need = match ty {
        10 => 4,
        24 => 10,
        71 => 4,
        _ => {
            out.ignored_cells += 1;
            return Ok(());
        }
    };
    if ids.len() < need {
        return Err(ParseError::file(
            "cells",
            format!(
                "cell {cell} of type {ty} has {} points (needs {need})",
                ids.len()
            ),
        ));
    }
    if ty != 10 {
        out.higher_order_tets += 1;
    }
    let mut t = [0u32; 4];
    for k in 0..4 {
        let i = ids[k];
        if i < 0 || i as usize >= out.nodes.len() {
            return Err(ParseError::file(
                "cells",
                format!(
                    "cell {cell} refers to point {i}, but there are {} points",
                    out.nodes.len()
                ),
            ));
        }
        t[k] = i as u32;
    }
    out.tets.push(t);
    Ok(())
}

/// Writes nodes (m) and tetrahedra as a legacy ASCII VTK file (version 3.0,
/// classic `CELLS` list, cell type 10), readable by every VTK version.
pub fn write_vtk<W: Write>(
    w: &mut W,
    nodes: &[Point3<f64>],
    tets: &[[u32; 4]],
) -> std::io::Result<()> {
    writeln!(
        w,
        "# vtk DataFile Version 3.0\nfissure tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID"
    )?;
    writeln!(w, "POINTS {} double", nodes.len())?;
    for p in nodes {
        writeln!(w, "{:?} {:?} {:?}", p.x, p.y, p.z)?;
    }
    writeln!(w, "CELLS {} {}", tets.len(), 5 * tets.len())?;
    for t in tets {
        writeln!(w, "4 {} {} {} {}", t[0], t[1], t[2], t[3])?;
    }
    writeln!(w, "CELL_TYPES {}", tets.len())?;
    for _ in tets {
        writeln!(w, "10")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let mesh = crate::mesh::blocks::cube(0.01, 2);
        let mut buf = Vec::new();
        write_vtk(&mut buf, &mesh.nodes, &mesh.tets).unwrap();
        let raw = parse(&buf).unwrap();
        assert_eq!(raw.nodes, mesh.nodes);
        assert_eq!(raw.tets, mesh.tets);
    }

    #[test]
    fn version_51_ascii_with_other_cells() {
        let text = b"# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\nCELLS 4 11\nOFFSETS vtktypeint64\n0 3 7 11\nCONNECTIVITY vtktypeint64\n0 1 2 0 1 2 3 1 2 3 4\nCELL_TYPES 3\n5 10 10\nPOINT_DATA 5\n";
        let raw = parse(text).unwrap();
        assert_eq!(raw.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
        assert_eq!(raw.ignored_cells, 1);
        let bad = b"# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 1 double\n0 0 0\nCELLS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 0 0 7\nCELL_TYPES 1\n10\n";
        let e = parse(bad).unwrap_err();
        assert!(e.message.contains("point 7"), "{e}");
    }
}
