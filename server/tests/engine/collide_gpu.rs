//! The wgpu collision backends give the same answers as the f64 brute force
//! (`collide::rays::brute::BruteForce`, the CPU reference): same triangle ids and the
//! same `t, u, v` bit for bit, on grids
//! with rays through vertices and edges, parallel rays, degenerate triangles,
//! near-ties, and closed surfaces deforming over several steps (BVH refit).
//!
//! Runs on any wgpu adapter, lavapipe included. Without an adapter the tests fail
//! when `CI` is set and print a skip notice otherwise.

use std::time::Instant;

use fissure_engine::collide::rays::gpu::{
    self, GpuBruteForce, GpuBvh, GpuError, GpuMethod, RefitMode,
};
use fissure_engine::collide::rays::ray::watertight;
use fissure_engine::collide::{BruteForce, NodeHits, RayBackend, SurfaceError};
use nalgebra::{Point3, Vector3};

/// Small deterministic generator (SplitMix64), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn unit(&mut self) -> Vector3<f64> {
        loop {
            let v = Vector3::new(
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            );
            let n = v.norm();
            if n > 0.1 && n < 1.0 {
                return v / n;
            }
        }
    }
}

/// The backend, or `None` with a notice when no adapter exists outside CI.
fn or_skip<T>(made: Result<T, GpuError>) -> Option<T> {
    match made {
        Ok(b) => Some(b),
        Err(GpuError::NoAdapter(reason)) => {
            if std::env::var_os("CI").is_some() {
                panic!(
                    "CI is set but no GPU adapter was found ({reason}); install mesa-vulkan-drivers (lavapipe)"
                );
            }
            eprintln!("skipped: no GPU adapter ({reason})");
            None
        }
        Err(e) => panic!("GPU backend creation failed: {e}"),
    }
}

/// Both GPU backends (the BVH with either refit) on one surface.
struct Gpus {
    brute: GpuBruteForce,
    bvh: GpuBvh,
    bvh_cpu: GpuBvh,
}

impl Gpus {
    fn all(&mut self) -> [&mut dyn RayBackend; 3] {
        [&mut self.brute, &mut self.bvh, &mut self.bvh_cpu]
    }
    /// Ray sides the host had to settle by brute force, per backend.
    fn fallbacks(&self) -> [u64; 3] {
        [
            self.brute.fallbacks(),
            self.bvh.fallbacks(),
            self.bvh_cpu.fallbacks(),
        ]
    }
}

/// The backends (`None` when skipped).
fn backends(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Option<Gpus> {
    let brute = or_skip(GpuBruteForce::try_new(triangles, positions))?;
    let bvh = or_skip(GpuBvh::try_new(triangles, positions))?;
    let mut bvh_cpu = or_skip(GpuBvh::try_new(triangles, positions))?;
    bvh_cpu.set_refit_mode(RefitMode::Cpu);
    Some(Gpus {
        brute,
        bvh,
        bvh_cpu,
    })
}

/// The CPU reference answers (`collide::rays::brute::BruteForce`, watertight test).
fn reference(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
    origins: &[Point3<f64>],
    dirs: &[Vector3<f64>],
) -> Vec<NodeHits> {
    let mut brute = BruteForce::new(triangles, positions).expect("a valid test surface");
    let mut out = Vec::new();
    brute.cast(origins, dirs, &mut out);
    out
}

fn assert_same(got: &[NodeHits], want: &[NodeHits], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: ray count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        for (side, a, b) in [("behind", g.behind, w.behind), ("front", g.front, w.front)] {
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    assert_eq!(
                        a.triangle, b.triangle,
                        "{what}: ray {i} {side}: triangle {a:?} vs reference {b:?}"
                    );
                    // The host decides with the reference's own f64 code.
                    assert!(
                        a.t.to_bits() == b.t.to_bits()
                            && a.u.to_bits() == b.u.to_bits()
                            && a.v.to_bits() == b.v.to_bits(),
                        "{what}: ray {i} {side}: {a:?} vs reference {b:?}"
                    );
                }
                _ => panic!("{what}: ray {i} {side}: {a:?} vs reference {b:?}"),
            }
        }
    }
}

/// Casts with every backend and compares with the CPU reference.
fn check(
    backends: &mut Gpus,
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
    origins: &[Point3<f64>],
    dirs: &[Vector3<f64>],
    what: &str,
) -> Vec<NodeHits> {
    let want = reference(triangles, positions, origins, dirs);
    let mut got = Vec::new();
    for b in backends.all() {
        b.cast(origins, dirs, &mut got);
        assert_same(
            &got,
            &want,
            &format!("{what} [{}/{}]", b.backend(), b.method()),
        );
    }
    want
}

/// A planar grid of `n x n` unit-1/8 cells at z = 0, two triangles per cell
/// (diagonals alternating), counter-clockwise seen from +z; vertex (i, j) at
/// index `i + (n + 1) j`. Coordinates are exact in binary.
fn grid(n: usize) -> (Vec<[u32; 3]>, Vec<Point3<f64>>) {
    let h = 0.125;
    let positions: Vec<Point3<f64>> = (0..=n)
        .flat_map(|j| (0..=n).map(move |i| Point3::new(i as f64 * h, j as f64 * h, 0.0)))
        .collect();
    let id = |i: usize, j: usize| (i + (n + 1) * j) as u32;
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            } else {
                triangles.push([a, b, d]);
                triangles.push([b, c, d]);
            }
        }
    }
    (triangles, positions)
}

/// A closed UV sphere of radius `r` about `c`: `slices * 2 * (stacks - 1)`
/// triangles, outward counter-clockwise.
fn sphere(
    c: Point3<f64>,
    r: f64,
    slices: usize,
    stacks: usize,
) -> (Vec<[u32; 3]>, Vec<Point3<f64>>) {
    use std::f64::consts::{PI, TAU};
    let mut positions = vec![c + Vector3::new(0.0, 0.0, r)];
    for k in 1..stacks {
        let th = PI * k as f64 / stacks as f64;
        for s in 0..slices {
            let ph = TAU * s as f64 / slices as f64;
            positions
                .push(c + r * Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()));
        }
    }
    positions.push(c + Vector3::new(0.0, 0.0, -r));
    let south = (positions.len() - 1) as u32;
    let ring = |k: usize, s: usize| (1 + (k - 1) * slices + s % slices) as u32;
    let mut triangles = Vec::new();
    for s in 0..slices {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(stacks - 1, s + 1), ring(stacks - 1, s)]);
    }
    for k in 1..stacks - 1 {
        for s in 0..slices {
            let (a, b, c, d) = (
                ring(k, s),
                ring(k + 1, s),
                ring(k + 1, s + 1),
                ring(k, s + 1),
            );
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    (triangles, positions)
}

#[test]
fn errors_name_the_bad_input() {
    let positions = vec![Point3::origin(); 3];
    match gpu::GpuBruteForce::try_new(&[[0, 1, 7]], &positions) {
        Err(GpuError::Surface(SurfaceError::VertexOutOfRange {
            triangle: 0,
            vertex: 7,
            vertices: 3,
        })) => {}
        other => panic!("expected VertexOutOfRange, got {:?}", other.err()),
    }
    let mut bad = positions.clone();
    bad[1].y = f64::NAN;
    match gpu::GpuBvh::try_new(&[[0, 1, 2]], &bad) {
        Err(GpuError::Surface(SurfaceError::NonFinite { vertex: 1 })) => {}
        other => panic!("expected NonFinite, got {:?}", other.err()),
    }
}

#[test]
fn backend_or_cpu_falls_back_on_bad_surface() {
    let positions = vec![Point3::origin(); 3];
    let triangles = vec![[0u32, 1, 9]];
    let b = gpu::backend_or_cpu(
        GpuMethod::Bvh,
        &triangles,
        &positions,
        || -> Box<dyn RayBackend> {
            Box::new(BruteForce::new(&[], &[]).expect("an empty surface"))
        },
    );
    assert_eq!(b.backend(), "cpu");
}

#[test]
fn grid_vertices_edges_parallel_and_degenerate() {
    let n = 8;
    let (mut triangles, mut positions) = grid(n);
    let h = 0.125;
    let plain = triangles.len();
    // Degenerate triangles over the grid: a repeated vertex, three collinear
    // vertices, a point triangle.
    let base = positions.len() as u32;
    positions.extend([
        Point3::new(0.3, 0.3, 0.2),
        Point3::new(0.6, 0.6, 0.2),
        Point3::new(0.9, 0.9, 0.2),
        Point3::new(0.4, 0.7, -0.3),
    ]);
    triangles.extend([
        [base, base, base + 1],
        [base, base + 1, base + 2],
        [base + 3, base + 3, base + 3],
    ]);
    let Some(mut backends) = backends(&triangles, &positions) else {
        return;
    };

    let mut origins = Vec::new();
    let mut dirs = Vec::new();
    let up = Vector3::new(0.0, 0.0, 1.0);
    // Vertical lines through every vertex, edge midpoint and cell centre, from
    // both sides and both directions.
    for j in 0..=2 * n {
        for i in 0..=2 * n {
            let p = Point3::new(i as f64 * h / 2.0, j as f64 * h / 2.0, 0.0);
            for (dz, d) in [(0.5, -up), (-0.5, up), (0.5, up)] {
                origins.push(p + Vector3::new(0.0, 0.0, dz));
                dirs.push(d);
            }
        }
    }
    let vertical = origins.len();
    // Oblique lines aimed at vertices and edge midpoints.
    let mut rng = Rng(7);
    for _ in 0..200 {
        let i = (rng.next_u64() % (2 * n as u64 + 1)) as f64;
        let j = (rng.next_u64() % (2 * n as u64 + 1)) as f64;
        let target = Point3::new(i * h / 2.0, j * h / 2.0, 0.0);
        let mut d = rng.unit();
        if d.z.abs() < 0.2 {
            d.z = 0.5;
            d = d.normalize();
        }
        origins.push(target - d * rng.range(-0.7, 0.7));
        dirs.push(d);
    }
    // Lines parallel to the grid: in its plane, and above it.
    for k in 0..20 {
        let y = k as f64 * h / 2.0;
        origins.push(Point3::new(-0.5, y, 0.0));
        dirs.push(Vector3::new(1.0, 0.0, 0.0));
        origins.push(Point3::new(0.2, y, 0.1));
        dirs.push(Vector3::new(1.0, 1.0, 0.0).normalize());
    }
    let want = check(
        &mut backends,
        &triangles,
        &positions,
        &origins,
        &dirs,
        "grid",
    );
    // Only the 20 lines lying in the grid's plane (every grid triangle along them
    // is a candidate of unknown t, 2 sides each) and the 15 vertical lines through
    // both a valence-8 grid vertex and the collinear degenerate triangle (9
    // near-equal candidates, one side each) may need the host's brute force.
    assert!(
        backends.fallbacks().iter().all(|&f| f <= 40 + 15),
        "{:?}",
        backends.fallbacks()
    );

    // Every vertical line through the grid's inside meets exactly one grid
    // triangle (watertight, no double hits at shared edges and vertices).
    let e = 1e-12;
    for (k, (o, d)) in origins[..vertical]
        .iter()
        .zip(&dirs[..vertical])
        .enumerate()
    {
        let inside = o.x > e && o.x < n as f64 * h - e && o.y > e && o.y < n as f64 * h - e;
        if !inside {
            continue;
        }
        let hits = triangles[..plain]
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|v| &positions[v as usize]);
                watertight(o, d, a, b, c).is_some()
            })
            .count();
        assert_eq!(
            hits, 1,
            "line {k} at ({}, {}) hits {hits} grid triangles",
            o.x, o.y
        );
        let w = want[k];
        assert_eq!(
            w.behind.is_some() as u32 + w.front.is_some() as u32,
            1,
            "line {k}: {w:?}"
        );
    }
    // Lines in the grid's plane hit nothing of the grid.
    for (o, d) in origins[origins.len() - 40..]
        .iter()
        .zip(&dirs[origins.len() - 40..])
        .step_by(2)
    {
        assert!(triangles[..plain].iter().all(|t| {
            let [a, b, c] = t.map(|v| &positions[v as usize]);
            watertight(o, d, a, b, c).is_none()
        }));
    }
}

#[test]
fn coincident_triangles_tie_to_lowest_index() {
    // Twelve copies of one triangle: more exact ties than the kernels keep (8),
    // so the host must settle them; the answer is the lowest index.
    let positions = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
    ];
    let triangles = vec![[0u32, 1, 2]; 12];
    let Some(mut backends) = backends(&triangles, &positions) else {
        return;
    };
    let origins = vec![Point3::new(0.25, 0.25, 1.0), Point3::new(0.25, 0.25, -1.0)];
    let dirs = vec![
        Vector3::new(0.0, 0.0, -1.0),
        Vector3::new(0.1, 0.0, 1.0).normalize(),
    ];
    let want = check(
        &mut backends,
        &triangles,
        &positions,
        &origins,
        &dirs,
        "coincident",
    );
    assert_eq!(want[0].front.map(|h| h.triangle), Some(0));
    // More ties than candidate slots: the host settles each front side.
    assert!(
        backends.fallbacks().iter().all(|&f| f >= 2),
        "{:?}",
        backends.fallbacks()
    );
    assert_eq!(want[1].front.map(|h| h.triangle), Some(0));
}

#[test]
fn random_soup_matches_reference() {
    let mut rng = Rng(42);
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for t in 0..600u32 {
        let c = Point3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        for _ in 0..3 {
            positions.push(c + rng.unit() * rng.range(0.01, 0.3));
        }
        triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    let Some(mut backends) = backends(&triangles, &positions) else {
        return;
    };
    let origins: Vec<Point3<f64>> = (0..400)
        .map(|_| {
            Point3::new(
                rng.range(-1.5, 1.5),
                rng.range(-1.5, 1.5),
                rng.range(-1.5, 1.5),
            )
        })
        .collect();
    let dirs: Vec<Vector3<f64>> = (0..400).map(|_| rng.unit()).collect();
    let want = check(
        &mut backends,
        &triangles,
        &positions,
        &origins,
        &dirs,
        "soup",
    );
    let found = want
        .iter()
        .filter(|h| h.behind.is_some() || h.front.is_some())
        .count();
    assert!(found > 100, "the scene should produce hits ({found})");
    assert_eq!(
        backends.fallbacks(),
        [0; 3],
        "the GPU candidates settle generic rays"
    );
}

/// Two spatula faces per instrument: `per_face` paired source nodes on a grid of
/// each face, rays along the face normals (DESIGN.md section 2).
fn spatula_rays(
    centre: Point3<f64>,
    normal: Vector3<f64>,
    per_face: (usize, usize),
    size: (f64, f64),
    thickness: f64,
    origins: &mut Vec<Point3<f64>>,
    dirs: &mut Vec<Vector3<f64>>,
) {
    let n = normal.normalize();
    let a = n.cross(&Vector3::new(0.3, 0.5, 0.8)).normalize();
    let b = n.cross(&a);
    for side in [1.0, -1.0] {
        for i in 0..per_face.0 {
            for j in 0..per_face.1 {
                let x = (i as f64 / (per_face.0 - 1) as f64 - 0.5) * size.0;
                let y = (j as f64 / (per_face.1 - 1) as f64 - 0.5) * size.1;
                origins.push(centre + a * x + b * y + n * (side * thickness / 2.0));
                dirs.push(n * side);
            }
        }
    }
}

#[test]
fn deforming_sphere_over_steps_matches_reference() {
    let c = Point3::new(0.01, -0.02, 0.03);
    let (triangles, rest) = sphere(c, 0.07, 40, 21);
    let Some(mut backends) = backends(&triangles, &rest) else {
        return;
    };
    let mut origins = Vec::new();
    let mut dirs = Vec::new();
    spatula_rays(
        c + Vector3::new(0.065, 0.0, 0.0),
        Vector3::new(0.0, 1.0, 0.2),
        (10, 6),
        (0.04, 0.02),
        0.002,
        &mut origins,
        &mut dirs,
    );
    spatula_rays(
        c + Vector3::new(-0.06, 0.02, 0.0),
        Vector3::new(0.1, 0.0, 1.0),
        (8, 8),
        (0.03, 0.03),
        0.002,
        &mut origins,
        &mut dirs,
    );
    // Lines through the rest surface's vertices, shared by 6 (40 at the poles)
    // triangles.
    let mut vertex_origins = Vec::new();
    let mut vertex_dirs = Vec::new();
    for (k, v) in rest.iter().enumerate().step_by(17) {
        let d = (v - c).normalize();
        vertex_origins.push(v + d * 0.01 * (k % 3) as f64);
        vertex_dirs.push(d);
    }
    let mut rng = Rng(3);
    for step in 0..4 {
        // Indent and stretch the sphere: a dent under the first spatula grows.
        let s = step as f64;
        let positions: Vec<Point3<f64>> = rest
            .iter()
            .map(|p| {
                let q = p - c;
                let dent = (-((q - Vector3::new(0.065, 0.0, 0.0)).norm_squared()) / 4e-4).exp();
                let jitter = Vector3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                ) * 2e-4
                    * s;
                c + q.component_mul(&Vector3::new(1.0 + 0.05 * s, 1.0, 1.0 - 0.03 * s))
                    - q * (0.2 * s * dent)
                    + jitter
            })
            .collect();
        for b in backends.all() {
            b.update_positions(&positions);
        }
        check(
            &mut backends,
            &triangles,
            &positions,
            &origins,
            &dirs,
            &format!("sphere step {step}"),
        );
        assert_eq!(
            backends.fallbacks(),
            [0; 3],
            "the GPU candidates settle the spatula rays"
        );
    }
    for b in backends.all() {
        b.update_positions(&rest);
    }
    check(
        &mut backends,
        &triangles,
        &rest,
        &vertex_origins,
        &vertex_dirs,
        "sphere vertices",
    );
    // Only the pole's 40-triangle fan exceeds the 8 candidates kept per side.
    assert!(
        backends.fallbacks().iter().all(|&f| f <= 2),
        "{:?}",
        backends.fallbacks()
    );
}

#[test]
fn ray_count_grows_and_shrinks() {
    let (triangles, positions) = sphere(Point3::origin(), 1.0, 12, 7);
    let Some(mut backends) = backends(&triangles, &positions) else {
        return;
    };
    let mut rng = Rng(11);
    for n in [1usize, 70, 300, 5, 0] {
        let origins: Vec<Point3<f64>> = (0..n)
            .map(|_| {
                Point3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                )
            })
            .collect();
        let dirs: Vec<Vector3<f64>> = (0..n).map(|_| rng.unit()).collect();
        check(
            &mut backends,
            &triangles,
            &positions,
            &origins,
            &dirs,
            &format!("{n} rays"),
        );
    }
}

/// Query times at the paper's size (about 15.9k triangles, 2 x 150 and 2 x 500
/// source nodes), with a check against the reference. Heavy on a software
/// adapter: `cargo test --release -p fissure-engine --test engine collide_gpu:: -- --ignored
/// --nocapture`.
#[test]
#[ignore]
fn timing_at_paper_size() {
    let c = Point3::origin();
    let (triangles, rest) = sphere(c, 0.07, 130, 62);
    assert_eq!(triangles.len(), 15_860);
    let Some(mut brute) = or_skip(GpuBruteForce::try_new(&triangles, &rest)) else {
        return;
    };
    let Some(mut bvh) = or_skip(GpuBvh::try_new(&triangles, &rest)) else {
        return;
    };
    println!(
        "adapter: {} ({:?})",
        bvh.adapter_name(),
        bvh.adapter_info().backend
    );
    let positions: Vec<Point3<f64>> = rest
        .iter()
        .map(|p| c + (p - c).component_mul(&Vector3::new(1.01, 1.0, 0.99)))
        .collect();
    for (per_face, size) in [((15, 10), (0.03, 0.02)), ((25, 20), (0.03, 0.024))] {
        let mut origins = Vec::new();
        let mut dirs = Vec::new();
        spatula_rays(
            c + Vector3::new(0.068, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.1),
            per_face,
            size,
            0.002,
            &mut origins,
            &mut dirs,
        );
        let t0 = Instant::now();
        let want = reference(&triangles, &positions, &origins, &dirs);
        let host_ms = t0.elapsed().as_secs_f64() * 1e3;
        let mut got = Vec::new();
        let reps = 20;
        let mut report = |name: &str, b: &mut dyn RayBackend| {
            b.update_positions(&positions);
            b.cast(&origins, &dirs, &mut got);
            assert_same(&got, &want, name);
            let t0 = Instant::now();
            for _ in 0..reps {
                b.update_positions(&positions);
                b.cast(&origins, &dirs, &mut got);
            }
            let ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
            println!(
                "{:>4} rays  {name:<22} {ms:8.2} ms/query (update + cast)",
                origins.len()
            );
        };
        report("gpu brute", &mut brute);
        bvh.set_refit_mode(RefitMode::Gpu);
        report("gpu bvh, gpu refit", &mut bvh);
        bvh.set_refit_mode(RefitMode::Cpu);
        report("gpu bvh, cpu refit", &mut bvh);
        println!(
            "{:>4} rays  {:<22} {host_ms:8.2} ms/query",
            origins.len(),
            "host f64 brute (1 thread)"
        );
        for mode in [RefitMode::Gpu, RefitMode::Cpu] {
            bvh.set_refit_mode(mode);
            let t0 = Instant::now();
            for _ in 0..reps {
                bvh.update_positions(&positions);
                bvh.refit_now();
            }
            let ms = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
            println!(
                "      refit {mode:?}: {ms:.2} ms (update_positions + refit, {} levels)",
                bvh.tree().depth()
            );
        }
        println!(
            "fallback sides so far: brute {}, bvh {}",
            brute.fallbacks(),
            bvh.fallbacks()
        );
    }
}

#[test]
fn bad_position_updates_are_ignored() {
    let (triangles, positions) = sphere(Point3::origin(), 1.0, 10, 6);
    let Some(mut backends) = backends(&triangles, &positions) else {
        return;
    };
    let mut nan = positions.clone();
    nan[3].x = f64::NAN;
    for b in backends.all() {
        // Too few positions, then a NaN: both leave the surface as it was.
        b.update_positions(&positions[..5]);
        b.update_positions(&nan);
    }
    let origins = vec![Point3::new(0.1, 0.2, -3.0), Point3::new(0.0, 0.0, 0.0)];
    let dirs = vec![Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.6, 0.0, 0.8)];
    let want = check(
        &mut backends,
        &triangles,
        &positions,
        &origins,
        &dirs,
        "after bad updates",
    );
    assert!(want.iter().all(|h| h.front.is_some()));
}
