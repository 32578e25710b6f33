//! Stanford PLY surfaces: ASCII, binary little and big endian. The `vertex`
//! element's `x`, `y`, `z` and the `face` element's `vertex_indices` (or
//! `vertex_index`) list are read; other properties and elements are parsed
//! and skipped. Polygons are split into a fan of triangles.

use super::cursor::{Cursor, show};
use super::{ParseError, SurfaceMesh};
use nalgebra::Point3;
use std::io::Write;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(t: &[u8]) -> Option<Self> {
        Some(match t {
            b"char" | b"int8" => Self::I8,
            b"uchar" | b"uint8" => Self::U8,
            b"short" | b"int16" => Self::I16,
            b"ushort" | b"uint16" => Self::U16,
            b"int" | b"int32" => Self::I32,
            b"uint" | b"uint32" => Self::U32,
            b"float" | b"float32" => Self::F32,
            b"double" | b"float64" => Self::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

#[derive(Debug)]
struct Property {
    name: Vec<u8>,
    /// `Some(count type)` for a list.
    list: Option<Scalar>,
    ty: Scalar,
}

#[derive(Debug)]
struct Element {
    name: Vec<u8>,
    count: u64,
    props: Vec<Property>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    Binary { big: bool },
}

fn read_scalar(
    cur: &mut Cursor<'_>,
    f: Format,
    ty: Scalar,
    field: &str,
) -> Result<f64, ParseError> {
    let big = match f {
        Format::Ascii => return cur.f64(field),
        Format::Binary { big } => big,
    };
    let b = cur.take(ty.size(), field)?;
    macro_rules! get {
        ($t:ty, $n:expr) => {{
            let mut a = [0u8; $n];
            a.copy_from_slice(b);
            (if big {
                <$t>::from_be_bytes(a)
            } else {
                <$t>::from_le_bytes(a)
            }) as f64
        }};
    }
    let v = match ty {
        Scalar::I8 => b[0] as i8 as f64,
        Scalar::U8 => b[0] as f64,
        Scalar::I16 => get!(i16, 2),
        Scalar::U16 => get!(u16, 2),
        Scalar::I32 => get!(i32, 4),
        Scalar::U32 => get!(u32, 4),
        Scalar::F32 => get!(f32, 4),
        Scalar::F64 => get!(f64, 8),
    };
    if v.is_finite() {
        Ok(v)
    } else {
        Err(cur.err(field, "not a finite number"))
    }
}

/// Parses a PLY file.
pub fn parse(bytes: &[u8]) -> Result<SurfaceMesh, ParseError> {
    let mut cur = Cursor::new(bytes);
    if cur.line_bytes().map(|l| l.trim_ascii()) != Some(b"ply") {
        return Err(ParseError {
            loc: super::Loc::Line(1),
            field: "magic".into(),
            message: "expected 'ply'".into(),
        });
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let line = cur
            .line_bytes()
            .ok_or_else(|| cur.err("end_header", "missing before the end of the file"))?;
        let mut t = line
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty());
        let err = |c: &Cursor<'_>, field: &str, m: String| ParseError {
            loc: super::Loc::Line(c.line - 1),
            field: field.into(),
            message: m,
        };
        match t.next() {
            Some(b"format") => {
                format = Some(match t.next() {
                    Some(b"ascii") => Format::Ascii,
                    Some(b"binary_little_endian") => Format::Binary { big: false },
                    Some(b"binary_big_endian") => Format::Binary { big: true },
                    other => {
                        return Err(err(
                            &cur,
                            "format",
                            format!("'{}' not supported", show(other.unwrap_or_default())),
                        ));
                    }
                })
            }
            Some(b"element") => {
                let name = t.next().unwrap_or_default().to_vec();
                let count = t
                    .next()
                    .and_then(super::cursor::parse_token::<u64>)
                    .ok_or_else(|| err(&cur, "element", "missing or bad count".into()))?;
                elements.push(Element {
                    name,
                    count,
                    props: Vec::new(),
                });
            }
            Some(b"property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err(&cur, "property", "before any element".into()))?;
                let first = t.next().unwrap_or_default();
                let prop = if first == b"list" {
                    let ct = t.next().and_then(Scalar::parse);
                    let it = t.next().and_then(Scalar::parse);
                    match (ct, it) {
                        (Some(c), Some(i)) => Property {
                            name: t.next().unwrap_or_default().to_vec(),
                            list: Some(c),
                            ty: i,
                        },
                        _ => return Err(err(&cur, "property", "bad list types".into())),
                    }
                } else {
                    let ty = Scalar::parse(first).ok_or_else(|| {
                        err(
                            &cur,
                            "property",
                            format!("type '{}' not supported", show(first)),
                        )
                    })?;
                    Property {
                        name: t.next().unwrap_or_default().to_vec(),
                        list: None,
                        ty,
                    }
                };
                el.props.push(prop);
            }
            Some(b"end_header") => break,
            _ => {} // comment, obj_info, blank
        }
    }
    let format = format.ok_or_else(|| cur.err("format", "no format line in the header"))?;
    if let Format::Binary { .. } = format {
        cur.binary = true;
    }
    let mut out = SurfaceMesh::default();
    let mut list = Vec::new();
    for el in &elements {
        let min: usize = el
            .props
            .iter()
            .map(|p| match (format, p.list) {
                (Format::Ascii, _) => 2,
                (_, Some(c)) => c.size(),
                (_, None) => p.ty.size(),
            })
            .sum();
        let count = cur.check_count(el.count, min, "element count")?;
        let is_vertex = el.name == b"vertex";
        let is_face = el.name == b"face";
        let xyz: Vec<Option<usize>> = [b"x", b"y", b"z"]
            .iter()
            .map(|n| {
                el.props
                    .iter()
                    .position(|p| p.name == *n && p.list.is_none())
            })
            .collect();
        if is_vertex && xyz.iter().any(Option::is_none) {
            return Err(cur.err("vertex", "the vertex element lacks x, y or z"));
        }
        if is_vertex {
            out.vertices.reserve(count);
        }
        for item in 0..count {
            let mut p = [0.0; 3];
            for (k, prop) in el.props.iter().enumerate() {
                let name = String::from_utf8_lossy(&prop.name).into_owned();
                match prop.list {
                    None => {
                        let v = read_scalar(&mut cur, format, prop.ty, &name)?;
                        if is_vertex {
                            for c in 0..3 {
                                if xyz[c] == Some(k) {
                                    p[c] = v;
                                }
                            }
                        }
                    }
                    Some(ct) => {
                        let n = read_scalar(&mut cur, format, ct, &name)?;
                        if !(0.0..=u32::MAX as f64).contains(&n) || n.fract() != 0.0 {
                            return Err(cur.err(&name, format!("bad list length {n}")));
                        }
                        let each = if format == Format::Ascii {
                            2
                        } else {
                            prop.ty.size()
                        };
                        let n = cur.check_count(n as u64, each, &name)?;
                        list.clear();
                        for _ in 0..n {
                            list.push(read_scalar(&mut cur, format, prop.ty, &name)?);
                        }
                        let indices =
                            prop.name == b"vertex_indices" || prop.name == b"vertex_index";
                        if is_face && indices {
                            if n < 3 {
                                return Err(cur.err(&name, format!("face {item} has {n} vertices")));
                            }
                            let nv = out.vertices.len() as f64;
                            if let Some(bad) = list
                                .iter()
                                .find(|&&i| !(0.0..nv).contains(&i) || i.fract() != 0.0)
                            {
                                return Err(cur.err(
                                    &name,
                                    format!("face {item} refers to vertex {bad}, out of range"),
                                ));
                            }
                            for k in 1..n - 1 {
                                out.triangles.push([
                                    list[0] as u32,
                                    list[k] as u32,
                                    list[k + 1] as u32,
                                ]);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                out.vertices.push(Point3::from(p));
            }
        }
    }
    Ok(out)
}

/// Writes a binary little-endian PLY: `double` x, y, z and a
/// `list uchar int vertex_indices` per face.
pub fn write_ply<W: Write>(
    w: &mut W,
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> std::io::Result<()> {
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment fissure surface\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        vertices.len(),
        triangles.len()
    )?;
    for p in vertices {
        for c in [p.x, p.y, p.z] {
            w.write_all(&c.to_le_bytes())?;
        }
    }
    for t in triangles {
        w.write_all(&[3])?;
        for &i in t {
            w.write_all(&(i as i32).to_le_bytes())?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_with_extra_properties_and_binary_round_trip() {
        let text = b"ply\nformat ascii 1.0\ncomment x\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_indices\nelement edge 1\nproperty int a\nproperty int b\nend_header\n0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n4 0 1 2 3\n0 1\n";
        let s = parse(text).unwrap();
        assert_eq!(s.vertices.len(), 4);
        assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let mut buf = Vec::new();
        write_ply(&mut buf, &s.vertices, &s.triangles).unwrap();
        assert_eq!(parse(&buf).unwrap(), s);
        // A count larger than the file is refused before allocating.
        let huge = b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        assert_eq!(parse(huge).unwrap_err().field, "element count");
    }
}
