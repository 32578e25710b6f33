//! TetGen `.node` and `.ele` files (ASCII), 0- or 1-based (the first node's
//! number sets the base for both files, as in TetGen). `#` starts a comment.
//!
//! `.node`: `<points> <dim = 3> <attributes> <markers 0|1>`, then per point
//! `<index> <x> <y> <z> [attributes] [marker]`.
//! `.ele`: `<tets> <nodes per tet 4|10> <region attribute 0|1>`, then per tet
//! `<index> <n1> ... [attribute]`; 10-node tets keep their four corners.

use super::cursor::{Cursor, parse_token, show};
use super::{ParseError, RawVolume};
use nalgebra::Point3;
use std::io::Write;

/// Which of the two files an error is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Which {
    /// The `.node` file.
    Node,
    /// The `.ele` file.
    Ele,
}

/// The tokens of the next non-empty line (comments removed), with the
/// cursor's line number for errors.
fn next_line<'a>(cur: &mut Cursor<'a>, toks: &mut Vec<&'a [u8]>) -> bool {
    loop {
        let line_no = cur.line;
        let Some(line) = cur.line_bytes() else {
            return false;
        };
        let line = match line.iter().position(|&b| b == b'#') {
            Some(i) => &line[..i],
            None => line,
        };
        toks.clear();
        toks.extend(
            line.split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty()),
        );
        if !toks.is_empty() {
            cur.line = line_no; // report errors on this line
            return true;
        }
    }
}

fn field<T: std::str::FromStr>(
    cur: &Cursor<'_>,
    toks: &[&[u8]],
    k: usize,
    name: &str,
) -> Result<T, ParseError> {
    let t = toks.get(k).ok_or_else(|| cur.err(name, "missing"))?;
    parse_token(t).ok_or_else(|| cur.err(name, format!("'{}' is not a valid value", show(t))))
}

/// After [`next_line`], moves the cursor's line number past the line.
fn done(cur: &mut Cursor<'_>) {
    cur.line += 1;
}

/// Parses a `.node` and an `.ele` file.
pub fn parse(node: &[u8], ele: &[u8]) -> Result<RawVolume, (Which, ParseError)> {
    let (nodes, base) = parse_node(node).map_err(|e| (Which::Node, e))?;
    let mut out = RawVolume {
        nodes,
        ..Default::default()
    };
    parse_ele(ele, base, &mut out).map_err(|e| (Which::Ele, e))?;
    Ok(out)
}

fn parse_node(bytes: &[u8]) -> Result<(Vec<Point3<f64>>, i64), ParseError> {
    let mut cur = Cursor::new(bytes);
    let mut toks = Vec::new();
    if !next_line(&mut cur, &mut toks) {
        return Err(ParseError::file("header", "empty .node file"));
    }
    let n: u64 = field(&cur, &toks, 0, "number of points")?;
    let dim: u32 = field(&cur, &toks, 1, "dimension")?;
    if dim != 3 {
        return Err(cur.err("dimension", format!("{dim} (expected 3)")));
    }
    let attrs: usize = field(&cur, &toks, 2, "number of attributes").unwrap_or(0);
    let markers: usize = field(&cur, &toks, 3, "boundary markers").unwrap_or(0);
    done(&mut cur);
    let n = cur.check_count(n, 8, "number of points")?;
    let mut nodes = Vec::with_capacity(n);
    let mut base = 0i64;
    for k in 0..n {
        if !next_line(&mut cur, &mut toks) {
            return Err(cur.err("point", format!("{n} points declared, {k} found")));
        }
        let id: i64 = field(&cur, &toks, 0, "point index")?;
        if k == 0 {
            if id != 0 && id != 1 {
                return Err(cur.err("point index", format!("first index {id} (expected 0 or 1)")));
            }
            base = id;
        } else if id != base + k as i64 {
            return Err(cur.err(
                "point index",
                format!("{id} (expected {})", base + k as i64),
            ));
        }
        let mut p = [0.0; 3];
        for (c, name) in ["x", "y", "z"].iter().enumerate() {
            let v: f64 = field(&cur, &toks, 1 + c, name)?;
            if !v.is_finite() {
                return Err(cur.err(name, "not a finite number"));
            }
            p[c] = v;
        }
        if toks.len() > 4 + attrs + markers.min(1) {
            return Err(cur.err(
                "point",
                format!(
                    "{} values, expected at most {}",
                    toks.len(),
                    4 + attrs + markers.min(1)
                ),
            ));
        }
        nodes.push(Point3::from(p));
        done(&mut cur);
    }
    Ok((nodes, base))
}

fn parse_ele(bytes: &[u8], base: i64, out: &mut RawVolume) -> Result<(), ParseError> {
    let mut cur = Cursor::new(bytes);
    let mut toks = Vec::new();
    if !next_line(&mut cur, &mut toks) {
        return Err(ParseError::file("header", "empty .ele file"));
    }
    let n: u64 = field(&cur, &toks, 0, "number of tetrahedra")?;
    let per: usize = field(&cur, &toks, 1, "nodes per tetrahedron")?;
    if per != 4 && per != 10 {
        return Err(cur.err("nodes per tetrahedron", format!("{per} (expected 4 or 10)")));
    }
    done(&mut cur);
    let n = cur.check_count(n, 2 * (per + 1), "number of tetrahedra")?;
    out.tets.reserve(n);
    for k in 0..n {
        if !next_line(&mut cur, &mut toks) {
            return Err(cur.err("tetrahedron", format!("{n} tetrahedra declared, {k} found")));
        }
        let _id: i64 = field(&cur, &toks, 0, "tetrahedron index")?;
        let mut t = [0u32; 4];
        for c in 0..per {
            let v: i64 = field(&cur, &toks, 1 + c, "node")?;
            let i = v - base;
            if i < 0 || i as usize >= out.nodes.len() {
                return Err(cur.err(
                    "node",
                    format!("tetrahedron {k} refers to node {v}, out of range"),
                ));
            }
            if c < 4 {
                t[c] = i as u32;
            }
        }
        if per == 10 {
            out.higher_order_tets += 1;
        }
        out.tets.push(t);
        done(&mut cur);
    }
    Ok(())
}

/// Writes a `.node` file (1-based, no attributes or markers).
pub fn write_node<W: Write>(w: &mut W, nodes: &[Point3<f64>]) -> std::io::Result<()> {
    writeln!(w, "{} 3 0 0", nodes.len())?;
    for (i, p) in nodes.iter().enumerate() {
        writeln!(w, "{} {:?} {:?} {:?}", i + 1, p.x, p.y, p.z)?;
    }
    Ok(())
}

/// Writes an `.ele` file (1-based, 4 nodes, no attribute).
pub fn write_ele<W: Write>(w: &mut W, tets: &[[u32; 4]]) -> std::io::Result<()> {
    writeln!(w, "{} 4 0", tets.len())?;
    for (i, t) in tets.iter().enumerate() {
        writeln!(
            w,
            "{} {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_zero_base() {
        let mesh = crate::mesh::blocks::cube(0.01, 2);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        write_node(&mut a, &mesh.nodes).unwrap();
        write_ele(&mut b, &mesh.tets).unwrap();
        let raw = parse(&a, &b).unwrap();
        assert_eq!(raw.nodes, mesh.nodes);
        assert_eq!(raw.tets, mesh.tets);
        let node0 = b"# zero based\n4 3 0 1\n0 0 0 0 1\n1 1 0 0 1\n2 0 1 0 1\n3 0 0 1 0\n";
        let ele0 = b"1 4 0\n0 0 1 2 3 # a tet\n";
        let raw = parse(node0, ele0).unwrap();
        assert_eq!(raw.tets, vec![[0, 1, 2, 3]]);
        let bad = b"1 4 0\n\n0 0 1 2 4\n";
        let (which, e) = parse(node0, bad).unwrap_err();
        assert_eq!(which, Which::Ele);
        assert_eq!(e.loc, super::super::Loc::Line(3));
        assert_eq!(e.field, "node");
    }
}
