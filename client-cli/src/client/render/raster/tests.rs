//! Tests of the rasteriser: projection, coverage, depth, shading.

use super::super::Rgb;
use super::super::colormap::Colormap;
use super::*;
use fissure_shared::surface::SurfaceError;
use nalgebra::Point3;

const BG: Rgb = [10, 20, 30];

fn opts(w: u32, h: u32, ss: u32) -> RenderOptions {
    RenderOptions {
        supersample: ss,
        background: Background::Solid(BG),
        ..RenderOptions::new(w, h)
    }
}

/// Camera on +z looking at the origin.
fn front_camera() -> Camera {
    Camera::look_at(
        Point3::new(0.0, 0.0, 10.0),
        Point3::origin(),
        Vector3::y(),
        30.0,
    )
}

fn quad(z: f64, half: f64) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    (
        vec![
            Point3::new(-half, -half, z),
            Point3::new(half, -half, z),
            Point3::new(half, half, z),
            Point3::new(-half, half, z),
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    )
}

fn is_bg(p: Rgb) -> bool {
    p == BG
}

#[test]
fn a_triangle_covers_its_projection_and_nothing_else() {
    let (w, h) = (200, 150);
    let cam = front_camera();
    let pos = [
        Point3::new(-1.0, -1.0, 0.0),
        Point3::new(1.5, -0.8, 0.0),
        Point3::new(0.2, 1.2, 0.0),
    ];
    let tri = [[0u32, 1, 2]];
    let mut r = Renderer::new(opts(w, h, 1)).unwrap();
    let img = r
        .render(
            &cam,
            &[MeshRef::new(
                &pos,
                &tri,
                Colouring::Uniform([200, 200, 200]),
            )],
        )
        .unwrap();
    let s = pos.map(|p| cam.project(&p, w, h).unwrap());
    let edge = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| {
        (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
    };
    let area = edge(s[0], s[1], s[2]);
    let mut mismatches = 0;
    let mut covered = 0;
    for y in 0..h {
        for x in 0..w {
            let p = [x as f64 + 0.5, y as f64 + 0.5];
            let e = [
                edge(s[1], s[2], p),
                edge(s[2], s[0], p),
                edge(s[0], s[1], p),
            ]
            .map(|v| v / area.signum());
            let inside = e.iter().all(|&v| v > 1e-6);
            let outside = e.iter().any(|&v| v < -1e-6);
            let bg = is_bg(img.get(x, y).unwrap());
            if !bg {
                covered += 1;
            }
            if (inside && bg) || (outside && !bg) {
                mismatches += 1;
            }
        }
    }
    assert_eq!(mismatches, 0);
    let expected = area.abs() / 2.0;
    assert!(
        (covered as f64 - expected).abs() < 0.02 * expected + 10.0,
        "{covered} vs {expected}"
    );
    // A lit front face is brighter than the ambient term alone.
    let c = [
        (s[0][0] + s[1][0] + s[2][0]) / 3.0,
        (s[0][1] + s[1][1] + s[2][1]) / 3.0,
    ];
    let px = img.get(c[0] as u32, c[1] as u32).unwrap();
    assert!(px[0] > (200.0 * 0.5) as u8, "centre {px:?}");
}

#[test]
fn a_nearer_triangle_hides_a_farther_one_in_either_order() {
    let (near_p, near_t) = quad(1.0, 1.0);
    let (far_p, far_t) = quad(-1.0, 2.0);
    let red = MeshRef::new(&near_p, &near_t, Colouring::Uniform([255, 0, 0])).flat();
    let green = MeshRef::new(&far_p, &far_t, Colouring::Uniform([0, 255, 0])).flat();
    let mut r = Renderer::new(opts(120, 120, 2)).unwrap();
    for order in [[red, green], [green, red]] {
        let img = r.render(&front_camera(), &order).unwrap();
        let c = img.get(60, 60).unwrap();
        assert!(c[0] > 100 && c[0] > c[1] + 100, "centre {c:?}");
        // Outside the near quad but inside the far one: green.
        let s = front_camera()
            .project(&Point3::new(1.6, 0.0, -1.0), 120, 120)
            .unwrap();
        let g = img.get(s[0] as u32, s[1] as u32).unwrap();
        assert!(g[1] > 100 && g[1] > g[0] + 100, "far {g:?}");
    }
}

#[test]
fn shared_edges_leave_no_gaps_and_back_faces_are_darker() {
    let (p, t) = quad(0.0, 1.0);
    let mut r = Renderer::new(opts(64, 64, 1)).unwrap();
    let cam = front_camera();
    let img = r
        .render(
            &cam,
            &[MeshRef::new(&p, &t, Colouring::Uniform([180, 180, 180])).flat()],
        )
        .unwrap();
    let lo = cam.project(&p[3], 64, 64).unwrap();
    let hi = cam.project(&p[1], 64, 64).unwrap();
    for y in (lo[1].ceil() as u32 + 1)..(hi[1].floor() as u32 - 1) {
        for x in (lo[0].ceil() as u32 + 1)..(hi[0].floor() as u32 - 1) {
            assert!(!is_bg(img.get(x, y).unwrap()), "gap at {x}, {y}");
        }
    }
    let front = img.get(32, 32).unwrap();
    // The same quad seen from behind (camera on -z).
    let back_cam = Camera::look_at(
        Point3::new(0.0, 0.0, -10.0),
        Point3::origin(),
        Vector3::y(),
        30.0,
    );
    let img = r
        .render(
            &back_cam,
            &[MeshRef::new(&p, &t, Colouring::Uniform([180, 180, 180])).flat()],
        )
        .unwrap();
    let back = img.get(32, 32).unwrap();
    assert!(!is_bg(back));
    assert!(back[0] < front[0], "back {back:?} front {front:?}");
}

#[test]
fn triangles_through_the_camera_plane_are_clipped() {
    let pos = [
        Point3::new(-1.0, -0.5, 5.0),
        Point3::new(1.0, -0.5, 5.0),
        Point3::new(0.0, -0.5, 20.0),
    ];
    let tri = [[0u32, 1, 2]];
    let mut r = Renderer::new(opts(80, 60, 2)).unwrap();
    let img = r
        .render(
            &front_camera(),
            &[MeshRef::new(&pos, &tri, Colouring::Uniform([255; 3]))],
        )
        .unwrap();
    let drawn = img.pixels().iter().filter(|p| !is_bg(**p)).count();
    assert!(drawn > 0 && drawn < 80 * 60);
}

#[test]
fn scalar_colouring_follows_the_map() {
    let (p, t) = quad(0.0, 1.0);
    let values = [0.0, 1.0, 1.0, 0.0];
    let mesh = MeshRef::new(
        &p,
        &t,
        Colouring::Scalar {
            values: &values,
            map: Colormap::Viridis,
            range: (0.0, 1.0),
        },
    );
    let mut r = Renderer::new(opts(100, 100, 2)).unwrap();
    let img = r.render(&front_camera(), &[mesh.flat()]).unwrap();
    let left = img.get(35, 50).unwrap();
    let right = img.get(65, 50).unwrap();
    // Viridis: purple-blue at 0 (blue > green), yellow-green at 1.
    assert!(left[2] > left[1], "left {left:?}");
    assert!(right[1] > right[2], "right {right:?}");
}

#[test]
fn bad_meshes_are_reported() {
    let (p, _) = quad(0.0, 1.0);
    let mut r = Renderer::new(opts(10, 10, 1)).unwrap();
    let bad_tri = [[0u32, 1, 9]];
    let e = r.render(
        &front_camera(),
        &[MeshRef::new(&p, &bad_tri, Colouring::Uniform([0; 3]))],
    );
    assert!(matches!(
        e,
        Err(RenderError::Surface {
            mesh: 0,
            source: SurfaceError::VertexOutOfRange {
                triangle: 0,
                vertex: 9,
                ..
            },
        })
    ));
    let ok_tri = [[0u32, 1, 2]];
    let cols = [[0u8; 3]; 2];
    let e = r.render(
        &front_camera(),
        &[MeshRef::new(&p, &ok_tri, Colouring::PerVertex(&cols))],
    );
    assert!(matches!(
        e,
        Err(RenderError::LengthMismatch {
            got: 2,
            vertices: 4,
            ..
        })
    ));
    let mut nan = p.clone();
    nan[2].x = f64::NAN;
    let e = r.render(
        &front_camera(),
        &[MeshRef::new(&nan, &ok_tri, Colouring::Uniform([0; 3]))],
    );
    assert!(matches!(
        e,
        Err(RenderError::Surface {
            source: SurfaceError::NonFinite { vertex: 2 },
            ..
        })
    ));
    // Degenerate triangles draw nothing and do not fail.
    let flat = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 1.0, 0.0),
        Point3::new(2.0, 2.0, 0.0),
    ];
    let img = r
        .render(
            &front_camera(),
            &[MeshRef::new(&flat, &ok_tri, Colouring::Uniform([255; 3]))],
        )
        .unwrap();
    assert!(img.pixels().iter().all(|p| is_bg(*p)));
    assert!(Renderer::new(opts(0, 10, 1)).is_err());
}

#[test]
fn frame_box_fits_every_corner_and_fills_the_image() {
    let (lo, hi) = (Point3::new(0.0, 0.0, 0.0), Point3::new(0.06, 0.03, 0.03));
    for (az, el) in [(-60.0, 30.0), (0.0, 0.0), (90.0, 89.0), (200.0, -20.0)] {
        let cam = Camera::orbit_box(lo, hi, az, el, 35.0, 4.0 / 3.0);
        let (mut xl, mut xh, mut yl, mut yh) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for i in 0..8 {
            let p = Point3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let s = cam.project(&p, 800, 600).unwrap();
            xl = xl.min(s[0]);
            xh = xh.max(s[0]);
            yl = yl.min(s[1]);
            yh = yh.max(s[1]);
        }
        assert!(
            xl >= -0.5 && yl >= -0.5 && xh <= 800.5 && yh <= 600.5,
            "({az}, {el}): {xl} {xh} {yl} {yh}"
        );
        // Tight in at least one direction (90 % fill), roughly centred.
        let fill = ((xh - xl) / 800.0).max((yh - yl) / 600.0);
        assert!(fill > 0.85 && fill < 0.95, "({az}, {el}): fill {fill}");
        assert!(((xl + xh) / 2.0 - 400.0).abs() < 8.0 && ((yl + yh) / 2.0 - 300.0).abs() < 8.0);
    }
}

#[test]
fn cuboid_is_closed_and_outward() {
    let pose = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.3, -0.2, 0.5));
    let half = Vector3::new(0.5, 1.0, 2.0);
    let m = TriMesh::cuboid(&pose, half, [0; 3]);
    // Signed volume by the divergence theorem: sum over faces of
    // (a . (b x c)) / 6; positive for outward orientation.
    let vol: f64 = m
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.positions[i as usize].coords);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum();
    assert!(
        (vol - 8.0 * half.x * half.y * half.z).abs() < 1e-12,
        "volume {vol}"
    );
}

#[test]
fn arrow_reaches_its_tip_and_zero_arrows_are_empty() {
    let o = Point3::new(0.1, 0.2, 0.3);
    let v = Vector3::new(0.0, -0.03, 0.04);
    let m = TriMesh::arrow(o, v, 0.001, [0; 3]);
    let along = m
        .positions
        .iter()
        .map(|p| (p - o).dot(&v.normalize()))
        .fold(f64::MIN, f64::max);
    assert!((along - v.norm()).abs() < 1e-12);
    let behind = m
        .positions
        .iter()
        .map(|p| (p - o).dot(&v.normalize()))
        .fold(f64::MAX, f64::min);
    assert!(behind.abs() < 1e-12);
    assert!(
        m.triangles
            .iter()
            .flatten()
            .all(|&i| (i as usize) < m.positions.len())
    );
    assert!(
        TriMesh::arrow(o, Vector3::zeros(), 0.001, [0; 3])
            .triangles
            .is_empty()
    );
    assert!(
        TriMesh::arrow(o, Vector3::new(f64::NAN, 0.0, 0.0), 0.001, [0; 3])
            .triangles
            .is_empty()
    );
    // Pointing straight down (antiparallel to the build axis).
    let down = TriMesh::arrow(o, Vector3::new(0.0, 0.0, -0.05), 0.001, [0; 3]);
    let lowest = down.positions.iter().map(|p| p.z).fold(f64::MAX, f64::min);
    assert!((lowest - (o.z - 0.05)).abs() < 1e-12);
}
