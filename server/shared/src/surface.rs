//! The checks every stage that indexes a triangle surface makes before it
//! trusts it (the CPU and GPU ray backends, the contact pipeline, the
//! rasterizer of clients): vertex indices in range, positions finite, counts
//! within what the stage's tables address. One error type, [`SurfaceError`],
//! so that a bad surface is reported in the same words wherever it is caught.
//! It lives here, the lowest crate the engine and clients share.

use nalgebra::Point3;

/// What is wrong with a triangle surface (indices into `positions`, m).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SurfaceError {
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "triangle {triangle} refers to vertex {vertex}, but the surface has {vertices} vertices"
    )]
    VertexOutOfRange {
        /// Triangle index.
        triangle: usize,
        /// The vertex index it names.
        vertex: u32,
        /// Number of vertices given.
        vertices: usize,
    },
    /// A triangle index (handed back by a ray backend) names no triangle.
    #[error("triangle {triangle} is out of range: the surface has {triangles} triangles")]
    TriangleOutOfRange {
        /// The triangle index given.
        triangle: usize,
        /// Number of triangles of the surface.
        triangles: usize,
    },
    /// A vertex position is NaN or infinite.
    #[error("surface vertex {vertex} has a non-finite coordinate")]
    NonFinite {
        /// Vertex index.
        vertex: usize,
    },
    /// More triangles or vertices than a stage's `u32` tables can index.
    #[error("{count} {what} are more than a backend can index")]
    TooLarge {
        /// "triangles" or "vertices".
        what: &'static str,
        /// The count given.
        count: usize,
    },
}

/// Checks that every position is finite and every vertex index in range;
/// returns one more than the largest vertex index used (the number of
/// positions a stage needs). The first non-finite vertex is reported before
/// any index.
pub fn check_surface(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
) -> Result<usize, SurfaceError> {
    if let Some(vertex) = positions
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(SurfaceError::NonFinite { vertex });
    }
    let mut needed = 0usize;
    for (triangle, t) in triangles.iter().enumerate() {
        for &vertex in t {
            if vertex as usize >= positions.len() {
                return Err(SurfaceError::VertexOutOfRange {
                    triangle,
                    vertex,
                    vertices: positions.len(),
                });
            }
            needed = needed.max(vertex as usize + 1);
        }
    }
    Ok(needed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_surface_in_range_needs_its_largest_vertex_plus_one() {
        let p = vec![Point3::origin(); 5];
        assert_eq!(check_surface(&[[0, 1, 3]], &p), Ok(4));
    }

    #[test]
    fn an_index_past_the_vertices_is_named_with_its_triangle() {
        let p = vec![Point3::origin(); 3];
        let e = check_surface(&[[0, 1, 2], [0, 2, 7]], &p).unwrap_err();
        assert_eq!(
            e,
            SurfaceError::VertexOutOfRange {
                triangle: 1,
                vertex: 7,
                vertices: 3
            }
        );
        assert_eq!(
            e.to_string(),
            "triangle 1 refers to vertex 7, but the surface has 3 vertices"
        );
    }

    #[test]
    fn a_nan_vertex_is_named() {
        let mut p = vec![Point3::origin(); 3];
        p[2].y = f64::NAN;
        assert_eq!(
            check_surface(&[[0, 1, 2]], &p),
            Err(SurfaceError::NonFinite { vertex: 2 })
        );
    }
}
