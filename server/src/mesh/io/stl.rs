//! STL surfaces, ASCII and binary. STL stores each triangle with its own
//! three corners; vertices with bit-identical coordinates are merged (STL
//! writers repeat the exact same numbers for a shared corner). The facet
//! normals in the file are ignored; the orientation is the vertex order.
//!
//! A file is binary when its size is `84 + 50 n` for the triangle count `n`
//! in its header (binary files may also start with `solid`).

use super::cursor::{Cursor, show};
use super::{ParseError, SurfaceMesh};
use nalgebra::Point3;
use std::collections::HashMap;
use std::io::Write;

/// Merges bit-identical vertices.
struct Dedupe {
    map: HashMap<[u64; 3], u32>,
    out: SurfaceMesh,
}

impl Dedupe {
    fn vertex(&mut self, p: [f64; 3]) -> u32 {
        let key = p.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
        let next = self.out.vertices.len() as u32;
        *self.map.entry(key).or_insert_with(|| {
            self.out.vertices.push(Point3::from(p));
            next
        })
    }
}

/// Parses an STL file (ASCII or binary).
pub fn parse(bytes: &[u8]) -> Result<SurfaceMesh, ParseError> {
    let mut d = Dedupe {
        map: HashMap::new(),
        out: SurfaceMesh::default(),
    };
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        if bytes.len() == 84 + 50 * n {
            let mut cur = Cursor::new(bytes);
            cur.binary = true;
            cur.pos = 84;
            d.out.triangles.reserve(n);
            for _ in 0..n {
                cur.take(12, "normal")?;
                let mut t = [0u32; 3];
                for k in &mut t {
                    let p = [
                        cur.bin_f32(false, "x")?,
                        cur.bin_f32(false, "y")?,
                        cur.bin_f32(false, "z")?,
                    ];
                    *k = d.vertex(p);
                }
                cur.take(2, "attribute byte count")?;
                d.out.triangles.push(t);
            }
            return Ok(d.out);
        }
    }
    let mut cur = Cursor::new(bytes);
    cur.expect("solid")?;
    cur.line_bytes(); // the solid's name
    loop {
        match cur.token() {
            Some(b"facet") => {}
            Some(b"endsolid") | None => break,
            Some(t) => {
                return Err(cur.err("facet", format!("expected 'facet', found '{}'", show(t))));
            }
        }
        cur.expect("normal")?;
        for _ in 0..3 {
            cur.token();
        }
        cur.expect("outer")?;
        cur.expect("loop")?;
        let mut t = [0u32; 3];
        for k in &mut t {
            cur.expect("vertex")?;
            let p = [cur.f64("x")?, cur.f64("y")?, cur.f64("z")?];
            *k = d.vertex(p);
        }
        cur.expect("endloop")?;
        cur.expect("endfacet")?;
        d.out.triangles.push(t);
    }
    Ok(d.out)
}

/// Writes a binary STL (coordinates rounded to `f32`, facet normals from the
/// vertex order).
pub fn write_stl<W: Write>(
    w: &mut W,
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> std::io::Result<()> {
    if let Some(bad) = triangles
        .iter()
        .flatten()
        .find(|&&i| i as usize >= vertices.len())
    {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "a triangle refers to vertex {bad}, but there are {} vertices",
                vertices.len()
            ),
        ));
    }
    let mut header = [b' '; 80];
    header[..14].copy_from_slice(b"fissure binary");
    w.write_all(&header)?;
    w.write_all(&(triangles.len() as u32).to_le_bytes())?;
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        let n = (b - a).cross(&(c - a));
        let n = if n.norm() > 0.0 { n.normalize() } else { n };
        for v in [n.x, n.y, n.z, a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z] {
            w.write_all(&(v as f32).to_le_bytes())?;
        }
        w.write_all(&[0, 0])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_dedupes_and_binary_round_trips() {
        let text = b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n";
        let s = parse(text).unwrap();
        assert_eq!(s.vertices.len(), 4);
        assert_eq!(s.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        let mut buf = Vec::new();
        write_stl(&mut buf, &s.vertices, &s.triangles).unwrap();
        assert_eq!(buf.len(), 84 + 100);
        assert_eq!(parse(&buf).unwrap(), s);
        let e = parse(b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0\nendloop").unwrap_err();
        assert_eq!(e.field, "z");
        assert_eq!(e.loc, super::super::Loc::Line(5));
    }
}
