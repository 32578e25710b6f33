//! Simple blocks for tests and validation: the cube (and, later, the paper's
//! V- and U-shaped valleys).

use super::TetMesh;
use nalgebra::Point3;

/// A box `[0, size.x] x [0, size.y] x [0, size.z]` (m) split into `n` cells per
/// axis, each cell into six tetrahedra (Kuhn subdivision, conforming across
/// cells).
pub fn cuboid(size: [f64; 3], n: [usize; 3]) -> TetMesh {
    let [nx, ny, nz] = n.map(|k| k.max(1));
    let id = |i: usize, j: usize, k: usize| (i + (nx + 1) * (j + (ny + 1) * k)) as u32;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push(Point3::new(
                    size[0] * i as f64 / nx as f64,
                    size[1] * j as f64 / ny as f64,
                    size[2] * k as f64 / nz as f64,
                ));
            }
        }
    }
    // Kuhn triangulation: the six paths from corner 000 to 111 along unit steps.
    const PATHS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for path in PATHS {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]); 4];
                    for (s, &axis) in path.iter().enumerate() {
                        c[axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    // Even permutations of the axes give positive orientation.
                    let even = matches!(path, [0, 1, 2] | [1, 2, 0] | [2, 0, 1]);
                    if !even {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    TetMesh::new(nodes, tets).expect("the Kuhn subdivision of a box is valid")
}

/// Maps the nodes of a cuboid `[0, w] x [0, d] x [0, h]` so that its top face
/// follows `z = top(x)` while the bottom stays at `z = 0`: `z' = z * top(x) / h`.
/// The map is monotone in `z`, so orientation is kept when `top > 0`.
fn with_top(mut mesh: TetMesh, h: f64, top: impl Fn(f64) -> f64) -> TetMesh {
    for p in &mut mesh.nodes {
        p.z *= top(p.x) / h;
    }
    TetMesh::new(mesh.nodes, mesh.tets).expect("a monotone top profile keeps tets valid")
}

/// The paper's V-shaped valley: a block 60 x 30 x 30 mm whose top face has a
/// V groove along y, 20 mm deep and 24 mm wide at the top, centred at x = 30 mm.
/// 4,608 tetrahedra and 1,088 surface triangles.
pub fn v_valley() -> TetMesh {
    let (w, d, h) = (0.06, 0.03, 0.03);
    let (depth, half_width) = (0.02, 0.012);
    let mesh = cuboid([w, d, h], [16, 8, 6]);
    with_top(mesh, h, |x| {
        let s = ((x - 0.5 * w).abs() / half_width).min(1.0);
        h - depth * (1.0 - s)
    })
}

/// The paper's U-shaped valley: a block 60 x 30 x 30 mm whose top face has a
/// round-bottomed groove along y (a half-ellipse 24 mm wide, 20 mm deep)
/// centred at x = 30 mm. 4,608 tetrahedra and 1,088 surface triangles.
pub fn u_valley() -> TetMesh {
    let (w, d, h) = (0.06, 0.03, 0.03);
    let (depth, half_width) = (0.02, 0.012);
    let mesh = cuboid([w, d, h], [16, 8, 6]);
    with_top(mesh, h, |x| {
        let s = ((x - 0.5 * w) / half_width).clamp(-1.0, 1.0);
        h - depth * (1.0 - s * s).sqrt()
    })
}

/// A cube of side `size_m` with `n` cells per edge.
pub fn cube(size_m: f64, n: usize) -> TetMesh {
    cuboid([size_m; 3], [n; 3])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_volume_and_boundary() {
        let m = cube(0.02, 3);
        let v: f64 = (0..m.tets.len()).map(|t| m.signed_volume(t)).sum();
        assert!((v - 0.02f64.powi(3)).abs() < 1e-15);
        assert_eq!(m.tets.len(), 6 * 27);
        let s = m.boundary();
        // 6 faces x 3x3 squares x 2 triangles
        assert_eq!(s.triangles.len(), 108);
        // Closed surface: area-weighted normals sum to zero, and each normal points out.
        let c = Point3::new(0.01, 0.01, 0.01);
        for t in &s.triangles {
            let [a, b, d] = t.map(|i| m.nodes[s.to_volume[i as usize] as usize]);
            let n = (b - a).cross(&(d - a));
            assert!(n.dot(&(a - c)) > 0.0, "inward triangle {t:?}");
        }
    }

    #[test]
    fn valleys_are_valid_and_small() {
        for m in [v_valley(), u_valley()] {
            let s = m.boundary();
            assert_eq!(m.tets.len(), 4608);
            assert!(s.triangles.len() < 1500);
            // The groove's bottom is 20 mm below the top at the centre line.
            let lowest_top = m
                .nodes
                .iter()
                .filter(|p| (p.x - 0.03).abs() < 1e-9 && p.z > 1e-9)
                .map(|p| p.z)
                .fold(f64::INFINITY, f64::min);
            assert!(lowest_top > 0.0);
            let top_at_centre = m
                .nodes
                .iter()
                .filter(|p| (p.x - 0.03).abs() < 1e-9)
                .map(|p| p.z)
                .fold(0.0, f64::max);
            assert!((top_at_centre - 0.01).abs() < 1e-12, "{top_at_centre}");
        }
    }
}
