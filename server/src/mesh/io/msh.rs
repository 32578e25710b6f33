//! Gmsh MSH files, versions 2.2 and 4.1, ASCII and binary.
//!
//! Only the `$MeshFormat`, `$Nodes` and `$Elements` sections are read
//! (`$Entities` is parsed in binary 4.1 to step over it; every other section
//! is skipped to its `$End...` line). Node tags may be any positive integers
//! and need not be contiguous; elements of types 4 (4-node tetrahedron), 11
//! (10-node), 29, 30 and 31 (20-, 35-, 56-node) become tetrahedra of their
//! first four nodes (the corners); other element types are counted and
//! skipped.

use super::cursor::Cursor;
use super::{ParseError, RawVolume};
use nalgebra::Point3;
use std::collections::HashMap;
use std::io::Write;

/// Number of nodes of a Gmsh element type, `None` when unknown.
fn nodes_per_element(t: i64) -> Option<usize> {
    Some(match t {
        1 => 2,
        2 => 3,
        3 => 4,
        4 => 4,
        5 => 8,
        6 => 6,
        7 => 5,
        8 => 3,
        9 => 6,
        10 => 9,
        11 => 10,
        12 => 27,
        13 => 18,
        14 => 14,
        15 => 1,
        16 => 8,
        17 => 20,
        18 => 15,
        19 => 13,
        20 => 9,
        21 => 10,
        22 => 12,
        23 => 15,
        24 => 15,
        25 => 21,
        26 => 4,
        27 => 5,
        28 => 6,
        29 => 20,
        30 => 35,
        31 => 56,
        92 => 64,
        93 => 125,
        _ => return None,
    })
}

fn is_tet(t: i64) -> bool {
    matches!(t, 4 | 11 | 29 | 30 | 31)
}

/// How numbers are stored after the header.
#[derive(Clone, Copy)]
enum Mode {
    Ascii,
    /// Binary with `size_t` of 4 or 8 bytes; `big` when the file's byte order
    /// differs from little endian.
    Binary {
        size_t: usize,
        big: bool,
    },
}

struct Reader<'a> {
    cur: Cursor<'a>,
    mode: Mode,
}

impl Reader<'_> {
    fn size(&mut self, field: &str) -> Result<u64, ParseError> {
        match self.mode {
            Mode::Ascii => self.cur.parse(field),
            Mode::Binary { size_t: 8, big } => self.cur.bin_u64(big, field),
            Mode::Binary { big, .. } => self.cur.bin_u32(big, field).map(u64::from),
        }
    }
    fn int(&mut self, field: &str) -> Result<i64, ParseError> {
        match self.mode {
            Mode::Ascii => self.cur.parse(field),
            Mode::Binary { big, .. } => self.cur.bin_i32(big, field).map(i64::from),
        }
    }
    fn double(&mut self, field: &str) -> Result<f64, ParseError> {
        match self.mode {
            Mode::Ascii => self.cur.f64(field),
            Mode::Binary { big, .. } => self.cur.bin_f64(big, field),
        }
    }
    /// Minimum bytes of a size_t / int / double in the file.
    fn min_size(&self) -> usize {
        match self.mode {
            Mode::Ascii => 2,
            Mode::Binary { size_t, .. } => size_t,
        }
    }
    fn min_int(&self) -> usize {
        match self.mode {
            Mode::Ascii => 2,
            Mode::Binary { .. } => 4,
        }
    }
    fn min_double(&self) -> usize {
        match self.mode {
            Mode::Ascii => 2,
            Mode::Binary { .. } => 8,
        }
    }
}

/// Parses an MSH file (2.2 or 4.1, ASCII or binary).
pub fn parse(bytes: &[u8]) -> Result<RawVolume, ParseError> {
    let mut cur = Cursor::new(bytes);
    cur.expect("$MeshFormat")?;
    let version_tok = cur.token().ok_or_else(|| cur.err("version", "missing"))?;
    let version = match version_tok {
        b"4.1" => 41,
        b"2.2" | b"2.1" | b"2" | b"2.0" => 22,
        other => {
            return Err(cur.err(
                "version",
                format!(
                    "MSH version '{}' not supported (2.2 and 4.1 are)",
                    super::cursor::show(other)
                ),
            ));
        }
    };
    let file_type: u32 = cur.parse("file-type")?;
    let data_size: usize = cur.parse("data-size")?;
    let mode = match file_type {
        0 => Mode::Ascii,
        1 => {
            if data_size != 4 && data_size != 8 {
                return Err(cur.err("data-size", format!("{data_size} (expected 4 or 8)")));
            }
            // The line break, then the integer 1 in the file's byte order.
            cur.skip_ws_to_newline();
            let one = cur.take(4, "endianness")?;
            let big = match one {
                [1, 0, 0, 0] => false,
                [0, 0, 0, 1] => true,
                _ => return Err(cur.err("endianness", "expected the integer 1")),
            };
            Mode::Binary {
                size_t: data_size,
                big,
            }
        }
        t => return Err(cur.err("file-type", format!("{t} (expected 0 or 1)"))),
    };
    cur.expect("$EndMeshFormat")?;
    let mut r = Reader { cur, mode };
    let mut tags: HashMap<u64, u32> = HashMap::new();
    let mut out = RawVolume::default();
    let mut pending: Vec<(usize, [u64; 4])> = Vec::new();
    let (mut have_nodes, mut have_elements) = (false, false);
    while let Some(tok) = r.cur.token() {
        match tok {
            b"$Nodes" => {
                if have_nodes {
                    return Err(r.cur.err("$Nodes", "a second $Nodes section"));
                }
                if let Mode::Binary { .. } = r.mode {
                    r.cur.binary = true;
                    r.cur.skip_ws_to_newline();
                }
                if version == 41 {
                    nodes41(&mut r, &mut out.nodes, &mut tags)?;
                } else {
                    nodes22(&mut r, &mut out.nodes, &mut tags)?;
                }
                r.cur.binary = false;
                r.cur.expect("$EndNodes")?;
                have_nodes = true;
            }
            b"$Elements" => {
                if have_elements {
                    return Err(r.cur.err("$Elements", "a second $Elements section"));
                }
                if let Mode::Binary { .. } = r.mode {
                    r.cur.binary = true;
                    r.cur.skip_ws_to_newline();
                }
                if version == 41 {
                    elements41(&mut r, &mut out, &mut pending)?;
                } else {
                    elements22(&mut r, &mut out, &mut pending)?;
                }
                r.cur.binary = false;
                r.cur.expect("$EndElements")?;
                have_elements = true;
            }
            b"$Entities" if version == 41 && matches!(r.mode, Mode::Binary { .. }) => {
                r.cur.binary = true;
                r.cur.skip_ws_to_newline();
                entities41_binary(&mut r)?;
                r.cur.binary = false;
                r.cur.expect("$EndEntities")?;
            }
            t if t.starts_with(b"$") => {
                let mut end = b"$End".to_vec();
                end.extend_from_slice(&t[1..]);
                if !r.cur.skip_past(&end) {
                    return Err(r.cur.err(
                        &String::from_utf8_lossy(t),
                        format!(
                            "no {} before the end of the file",
                            String::from_utf8_lossy(&end)
                        ),
                    ));
                }
            }
            t => {
                return Err(r.cur.err(
                    "section",
                    format!("expected a $Section, found '{}'", super::cursor::show(t)),
                ));
            }
        }
    }
    if !have_nodes {
        return Err(ParseError::file("$Nodes", "the file has no $Nodes section"));
    }
    // Resolve node tags (elements may come before nodes in principle).
    out.tets.reserve(pending.len());
    for (element, t) in pending {
        let mut tet = [0u32; 4];
        for (k, tag) in t.iter().enumerate() {
            tet[k] = *tags.get(tag).ok_or_else(|| {
                ParseError::file(
                    "$Elements",
                    format!("tetrahedron {element} refers to node tag {tag}, which is not defined"),
                )
            })?;
        }
        out.tets.push(tet);
    }
    Ok(out)
}

impl Cursor<'_> {
    /// Skips spaces up to and including the next line break (the end of a
    /// header line before binary data).
    fn skip_ws_to_newline(&mut self) {
        while let Some(&b) = self.data.get(self.pos) {
            self.pos += 1;
            if b == b'\n' {
                self.line += 1;
                break;
            }
            if !b.is_ascii_whitespace() {
                self.pos -= 1;
                break;
            }
        }
    }
}

fn add_node(
    r: &Reader<'_>,
    nodes: &mut Vec<Point3<f64>>,
    tags: &mut HashMap<u64, u32>,
    tag: u64,
    p: Point3<f64>,
) -> Result<(), ParseError> {
    if nodes.len() >= u32::MAX as usize {
        return Err(r.cur.err("numNodes", "more than 2^32 - 1 nodes"));
    }
    if tags.insert(tag, nodes.len() as u32).is_some() {
        return Err(r
            .cur
            .err("nodeTag", format!("node tag {tag} defined twice")));
    }
    nodes.push(p);
    Ok(())
}

fn nodes41(
    r: &mut Reader<'_>,
    nodes: &mut Vec<Point3<f64>>,
    tags: &mut HashMap<u64, u32>,
) -> Result<(), ParseError> {
    let blocks = r.size("numEntityBlocks")?;
    let total = r.size("numNodes")?;
    let _min = r.size("minNodeTag")?;
    let _max = r.size("maxNodeTag")?;
    let per_node = r.min_size() + 3 * r.min_double();
    let total = r.cur.check_count(total, per_node, "numNodes")?;
    let blocks = r
        .cur
        .check_count(blocks, 3 * r.min_int() + r.min_size(), "numEntityBlocks")?;
    nodes.reserve(total);
    tags.reserve(total);
    for _ in 0..blocks {
        let dim = r.int("entityDim")?;
        let _entity = r.int("entityTag")?;
        let parametric = r.int("parametric")?;
        let n = r.size("numNodesInBlock")?;
        let n = r.cur.check_count(n, per_node, "numNodesInBlock")?;
        if nodes.len() + n > total {
            return Err(r.cur.err(
                "numNodesInBlock",
                format!("blocks hold more than numNodes = {total}"),
            ));
        }
        if !(0..=3).contains(&dim) {
            return Err(r.cur.err("entityDim", format!("{dim} (expected 0..3)")));
        }
        let extra = if parametric != 0 { dim as usize } else { 0 };
        let mut block_tags = Vec::with_capacity(n);
        for _ in 0..n {
            block_tags.push(r.size("nodeTag")?);
        }
        for tag in block_tags {
            let p = Point3::new(r.double("x")?, r.double("y")?, r.double("z")?);
            for _ in 0..extra {
                r.double("parametric coordinate")?;
            }
            add_node(r, nodes, tags, tag, p)?;
        }
    }
    if nodes.len() != total {
        return Err(r.cur.err(
            "numNodes",
            format!("{total} declared, {} found in the blocks", nodes.len()),
        ));
    }
    Ok(())
}

fn nodes22(
    r: &mut Reader<'_>,
    nodes: &mut Vec<Point3<f64>>,
    tags: &mut HashMap<u64, u32>,
) -> Result<(), ParseError> {
    // The count is always ASCII, on its own line.
    let binary = r.cur.binary;
    r.cur.binary = false;
    let n: u64 = r.cur.parse("number-of-nodes")?;
    r.cur.binary = binary;
    let per_node = match r.mode {
        Mode::Ascii => 8,
        Mode::Binary { .. } => 4 + 24,
    };
    if let Mode::Binary { .. } = r.mode {
        r.cur.skip_ws_to_newline();
    }
    let n = r.cur.check_count(n, per_node, "number-of-nodes")?;
    nodes.reserve(n);
    tags.reserve(n);
    for _ in 0..n {
        let tag = match r.mode {
            Mode::Ascii => r.cur.parse::<u64>("node-number")?,
            Mode::Binary { big, .. } => r.cur.bin_i32(big, "node-number")? as u32 as u64,
        };
        let p = Point3::new(r.double("x")?, r.double("y")?, r.double("z")?);
        add_node(r, nodes, tags, tag, p)?;
    }
    Ok(())
}

fn element(
    out: &mut RawVolume,
    pending: &mut Vec<(usize, [u64; 4])>,
    etype: i64,
    node_tags: &[u64],
    index: usize,
) {
    if is_tet(etype) {
        if etype != 4 {
            out.higher_order_tets += 1;
        }
        pending.push((
            index,
            [node_tags[0], node_tags[1], node_tags[2], node_tags[3]],
        ));
    } else {
        out.ignored_cells += 1;
    }
}

fn elements41(
    r: &mut Reader<'_>,
    out: &mut RawVolume,
    pending: &mut Vec<(usize, [u64; 4])>,
) -> Result<(), ParseError> {
    let blocks = r.size("numEntityBlocks")?;
    let total = r.size("numElements")?;
    let _min = r.size("minElementTag")?;
    let _max = r.size("maxElementTag")?;
    let total = r.cur.check_count(total, 2 * r.min_size(), "numElements")?;
    let blocks = r
        .cur
        .check_count(blocks, 3 * r.min_int() + r.min_size(), "numEntityBlocks")?;
    let mut seen = 0usize;
    let mut node_tags = Vec::new();
    for _ in 0..blocks {
        let _dim = r.int("entityDim")?;
        let _entity = r.int("entityTag")?;
        let etype = r.int("elementType")?;
        let per = nodes_per_element(etype).ok_or_else(|| {
            r.cur
                .err("elementType", format!("element type {etype} not supported"))
        })?;
        let n = r.size("numElementsInBlock")?;
        let n = r
            .cur
            .check_count(n, (per + 1) * r.min_size(), "numElementsInBlock")?;
        if seen + n > total {
            return Err(r.cur.err(
                "numElementsInBlock",
                format!("blocks hold more than numElements = {total}"),
            ));
        }
        if is_tet(etype) {
            pending.reserve(n);
        }
        for _ in 0..n {
            let _tag = r.size("elementTag")?;
            node_tags.clear();
            for _ in 0..per {
                node_tags.push(r.size("nodeTag")?);
            }
            element(out, pending, etype, &node_tags, seen);
            seen += 1;
        }
    }
    if seen != total {
        return Err(r.cur.err(
            "numElements",
            format!("{total} declared, {seen} found in the blocks"),
        ));
    }
    Ok(())
}

fn elements22(
    r: &mut Reader<'_>,
    out: &mut RawVolume,
    pending: &mut Vec<(usize, [u64; 4])>,
) -> Result<(), ParseError> {
    let binary = r.cur.binary;
    r.cur.binary = false;
    let total: u64 = r.cur.parse("number-of-elements")?;
    r.cur.binary = binary;
    let total = r.cur.check_count(total, 8, "number-of-elements")?;
    let mut node_tags = Vec::new();
    match r.mode {
        Mode::Ascii => {
            for index in 0..total {
                let _tag: u64 = r.cur.parse("elm-number")?;
                let etype: i64 = r.cur.parse("elm-type")?;
                let ntags: u64 = r.cur.parse("number-of-tags")?;
                let ntags = r.cur.check_count(ntags, 2, "number-of-tags")?;
                for _ in 0..ntags {
                    r.cur.parse::<i64>("tag")?;
                }
                let per = nodes_per_element(etype).ok_or_else(|| {
                    r.cur
                        .err("elm-type", format!("element type {etype} not supported"))
                })?;
                node_tags.clear();
                for _ in 0..per {
                    node_tags.push(r.cur.parse::<u64>("node-number-list")?);
                }
                element(out, pending, etype, &node_tags, index);
            }
        }
        Mode::Binary { big, .. } => {
            r.cur.skip_ws_to_newline();
            let mut index = 0;
            while index < total {
                let etype = r.cur.bin_i32(big, "elm-type")? as i64;
                let follow = r.cur.bin_i32(big, "number-of-elements-following")?;
                let ntags = r.cur.bin_i32(big, "number-of-tags")?;
                let per = nodes_per_element(etype).ok_or_else(|| {
                    r.cur
                        .err("elm-type", format!("element type {etype} not supported"))
                })?;
                if follow < 0 || ntags < 0 || index + follow as usize > total {
                    return Err(r.cur.err(
                        "number-of-elements-following",
                        format!(
                            "{follow} elements with {ntags} tags do not fit the declared {total}"
                        ),
                    ));
                }
                let each = 4 * (1 + ntags as usize + per);
                let follow =
                    r.cur
                        .check_count(follow as u64, each, "number-of-elements-following")?;
                if follow == 0 {
                    return Err(r.cur.err(
                        "number-of-elements-following",
                        "0 (a block must hold elements)",
                    ));
                }
                for _ in 0..follow {
                    r.cur.bin_i32(big, "elm-number")?;
                    for _ in 0..ntags {
                        r.cur.bin_i32(big, "tag")?;
                    }
                    node_tags.clear();
                    for _ in 0..per {
                        node_tags.push(r.cur.bin_i32(big, "node-number-list")? as u32 as u64);
                    }
                    element(out, pending, etype, &node_tags, index);
                    index += 1;
                }
            }
        }
    }
    Ok(())
}

/// Steps over a binary MSH 4.1 `$Entities` section.
fn entities41_binary(r: &mut Reader<'_>) -> Result<(), ParseError> {
    let counts = [
        r.size("numPoints")?,
        r.size("numCurves")?,
        r.size("numSurfaces")?,
        r.size("numVolumes")?,
    ];
    let (si, sd, ss) = (r.min_int(), r.min_double(), r.min_size());
    for (dim, &count) in counts.iter().enumerate() {
        let each = if dim == 0 {
            si + 3 * sd + ss
        } else {
            si + 6 * sd + 2 * ss
        };
        let count = r.cur.check_count(count, each, "numEntities")?;
        for _ in 0..count {
            r.int("entityTag")?;
            let coords = if dim == 0 { 3 } else { 6 };
            for _ in 0..coords {
                r.double("entity bounds")?;
            }
            let nphys = r.size("numPhysicalTags")?;
            let nphys = r.cur.check_count(nphys, si, "numPhysicalTags")?;
            for _ in 0..nphys {
                r.int("physicalTag")?;
            }
            if dim > 0 {
                let nb = r.size("numBounding")?;
                let nb = r.cur.check_count(nb, si, "numBounding")?;
                for _ in 0..nb {
                    r.int("boundingTag")?;
                }
            }
        }
    }
    Ok(())
}

/// Writes nodes (m) and tetrahedra as an ASCII MSH 4.1 file: one volume
/// entity, node tags `1..=N`, element type 4, coordinates in shortest
/// round-trip form (reading gives back the same `f64`).
pub fn write_msh41<W: Write>(
    w: &mut W,
    nodes: &[Point3<f64>],
    tets: &[[u32; 4]],
) -> std::io::Result<()> {
    let (n, m) = (nodes.len(), tets.len());
    writeln!(w, "$MeshFormat\n4.1 0 8\n$EndMeshFormat")?;
    writeln!(w, "$Entities\n0 0 0 1\n1 0 0 0 0 0 0 0 0\n$EndEntities")?;
    writeln!(w, "$Nodes\n1 {n} 1 {n}\n3 1 0 {n}")?;
    for i in 1..=n {
        writeln!(w, "{i}")?;
    }
    for p in nodes {
        writeln!(w, "{:?} {:?} {:?}", p.x, p.y, p.z)?;
    }
    writeln!(w, "$EndNodes\n$Elements\n1 {m} 1 {m}\n3 1 4 {m}")?;
    for (e, t) in tets.iter().enumerate() {
        writeln!(
            w,
            "{} {} {} {} {}",
            e + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        )?;
    }
    writeln!(w, "$EndElements")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_41() {
        let mesh = crate::mesh::blocks::cube(0.02, 2);
        let mut buf = Vec::new();
        write_msh41(&mut buf, &mesh.nodes, &mesh.tets).unwrap();
        let raw = parse(&buf).unwrap();
        assert_eq!(raw.nodes, mesh.nodes);
        assert_eq!(raw.tets, mesh.tets);
        assert_eq!(raw.ignored_cells, 0);
    }

    #[test]
    fn errors_name_line_and_field() {
        let text = b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 1 2\n3 1 0 2\n1\n2\n0 0 0\n1 x 0\n$EndNodes\n";
        let e = parse(text).unwrap_err();
        assert_eq!(e.loc, super::super::Loc::Line(10));
        assert_eq!(e.field, "y");
        let huge = b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 99999999999999 1 2\n";
        let e = parse(huge).unwrap_err();
        assert_eq!(e.field, "numNodes");
        let bad_ref = b"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1\n1 0 0 0\n$EndNodes\n$Elements\n1\n1 4 0 1 2 3 4\n$EndElements\n";
        let e = parse(bad_ref).unwrap_err();
        assert!(e.message.contains("node tag 2"), "{e}");
    }
}
