//! Wavefront OBJ surfaces: `v x y z [w]` vertices and `f` faces (`i`, `i/t`,
//! `i//n`, `i/t/n`; negative indices count back from the last vertex);
//! polygons are split into a fan of triangles from their first vertex. Other
//! statements (normals, texture coordinates, groups, lines) are skipped.

use super::cursor::{Cursor, parse_token, show};
use super::{ParseError, SurfaceMesh};
use nalgebra::Point3;
use std::io::Write;

/// Parses an OBJ file.
pub fn parse(bytes: &[u8]) -> Result<SurfaceMesh, ParseError> {
    let mut cur = Cursor::new(bytes);
    let mut out = SurfaceMesh::default();
    let mut face: Vec<u32> = Vec::new();
    loop {
        let line_no = cur.line;
        let Some(line) = cur.line_bytes() else { break };
        let err = |field: &str, message: String| ParseError {
            loc: super::Loc::Line(line_no),
            field: field.to_string(),
            message,
        };
        let mut toks = line
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty());
        match toks.next() {
            Some(b"v") => {
                let mut p = [0.0; 3];
                for (c, name) in ["x", "y", "z"].iter().enumerate() {
                    let t = toks.next().ok_or_else(|| err(name, "missing".into()))?;
                    let v: f64 =
                        parse_token(t)
                            .filter(|v: &f64| v.is_finite())
                            .ok_or_else(|| {
                                err(name, format!("'{}' is not a finite number", show(t)))
                            })?;
                    p[c] = v;
                }
                if out.vertices.len() >= u32::MAX as usize {
                    return Err(err("v", "more than 2^32 - 1 vertices".into()));
                }
                out.vertices.push(Point3::from(p));
            }
            Some(b"f") => {
                face.clear();
                for t in toks {
                    let idx = t.split(|&b| b == b'/').next().unwrap_or_default();
                    let i: i64 = parse_token(idx)
                        .ok_or_else(|| err("f", format!("'{}' is not a vertex index", show(t))))?;
                    let n = out.vertices.len() as i64;
                    let k = if i > 0 { i - 1 } else { n + i };
                    if i == 0 || k < 0 || k >= n {
                        return Err(err(
                            "f",
                            format!("vertex index {i} out of range ({n} vertices so far)"),
                        ));
                    }
                    face.push(k as u32);
                }
                if face.len() < 3 {
                    return Err(err(
                        "f",
                        format!("a face needs 3 vertices, found {}", face.len()),
                    ));
                }
                for k in 1..face.len() - 1 {
                    out.triangles.push([face[0], face[k], face[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Ok(out)
}

/// Writes vertices (m, shortest round-trip decimal form) and triangles.
pub fn write_obj<W: Write>(
    w: &mut W,
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> std::io::Result<()> {
    writeln!(
        w,
        "# fissure surface: {} vertices, {} triangles",
        vertices.len(),
        triangles.len()
    )?;
    for p in vertices {
        writeln!(w, "v {:?} {:?} {:?}", p.x, p.y, p.z)?;
    }
    for t in triangles {
        writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faces_forms_and_errors() {
        let text = b"# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1/1/1 2//1 3 -1\n";
        let s = parse(text).unwrap();
        assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let e = parse(b"v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap_err();
        assert_eq!(e.loc, super::super::Loc::Line(3));
        let e = parse(b"v 0 nan 0\n").unwrap_err();
        assert_eq!(e.field, "y");
    }
}
