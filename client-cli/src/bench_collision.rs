//! Collision-query benchmark: the paper's brute force against the refitted BVH,
//! timed side by side in one run (DESIGN.md section 7).
//!
//! One query is what a deformation step asks of the collision stage for all
//! spatulas: `update_positions` (the BVH refits here; the brute force copies)
//! followed by [`detect_many`] (rays, pairs, culling, enforced displacements).
//! Each row reports the mean wall time of a query, in ms; the speedup of a BVH
//! row is the brute-force time of the same configuration divided by its own.
//! Rayon uses its global pool: run with `RAYON_NUM_THREADS=1` for one core.

use fissure_server::collide::{
    BruteForce, Bvh, ContactOutput, ContactQuery, DetectOptions, History, HistoryMode, Instrument,
    NodeLayout, Plate, RayBackend, Stage, Tool, Workspace, detect_many,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::time::{Duration, Instant};

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchOptions {
    /// Face-node counts per face to measure (each one row pair).
    pub nodes_per_face: Vec<usize>,
    /// Number of spatulas (placed side by side along x, touching the top).
    pub spatulas: usize,
    /// Least time spent per row; at least `min_repeats` queries are timed.
    pub min_time: Duration,
    /// Least number of timed queries per row.
    pub min_repeats: usize,
    /// Also run the brute force (the reference; slow on large surfaces).
    pub brute: bool,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            nodes_per_face: vec![30, 150, 500],
            spatulas: 2,
            min_time: Duration::from_millis(500),
            min_repeats: 3,
            brute: true,
        }
    }
}

/// One measured configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    /// "brute" or "bvh".
    pub method: String,
    /// "cpu" (or a GPU backend's name).
    pub backend: String,
    /// Surface triangles.
    pub triangles: usize,
    /// Source nodes per face.
    pub nodes_per_face: usize,
    /// Spatulas in the query.
    pub spatulas: usize,
    /// Rays cast per query (all nodes of all spatulas).
    pub rays: usize,
    /// Mean wall time of one query (refit/update included), ms.
    pub ms_per_query: f64,
    /// Timed queries.
    pub repeats: usize,
    /// Surviving pairs of the query (same for every method).
    pub pairs: usize,
    /// Brute-force time over this row's time, measured in the same run.
    pub speedup: Option<f64>,
    /// Whether the pairs equal the brute-force pairs (None without brute force).
    pub matches_brute: Option<bool>,
}

/// Spatula poses touching the surface: plates lying flat on the top of the
/// bounding box, length along +x, face B (normal -z) 0.5 mm into the tissue and
/// face A 0.5 mm above it, spread along x over the middle of the box.
pub fn touching_poses(positions: &[Point3<f64>], count: usize) -> Vec<Isometry3<f64>> {
    let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
    let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
    for p in positions {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let c = nalgebra::center(&lo, &hi);
    let ext = hi - lo;
    // Instrument x (face A normal) -> +z, y -> -y, z (length) -> +x.
    let rot = UnitQuaternion::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
    (0..count)
        .map(|k| {
            let f = if count == 1 {
                0.0
            } else {
                k as f64 / (count - 1) as f64 - 0.5
            };
            let x = c.x + 0.3 * ext.x * f - 0.5 * PLATE_LENGTH + 0.37e-3;
            Isometry3::from_parts(Translation3::new(x, c.y + 0.11e-3, hi.z), rot)
        })
        .collect()
}

/// Spatula length of the benchmark, m (thickness 1 mm, width 10 mm).
const PLATE_LENGTH: f64 = 0.03;

fn time_queries(
    backend: &mut dyn RayBackend,
    positions: &[Point3<f64>],
    triangles: &[[u32; 3]],
    to_volume: &[u32],
    inst: &Instrument,
    poses: &[Isometry3<f64>],
    opts: &BenchOptions,
    first: &mut ContactOutput,
) -> (f64, usize) {
    let query = ContactQuery {
        positions,
        rest: positions,
        triangles,
        to_volume,
    };
    let mut hist: Vec<History> = poses
        .iter()
        .map(|_| History::new(inst, HistoryMode::ForceRate))
        .collect();
    let mut ws = Workspace::new();
    let mut run = |hist: &mut [History], out: &mut ContactOutput| {
        backend.update_positions(positions);
        let mut tools: Vec<Tool<'_>> = hist
            .iter_mut()
            .zip(poses)
            .map(|(h, p)| Tool {
                instrument: inst,
                pose: *p,
                history: h,
            })
            .collect();
        detect_many(
            backend,
            &query,
            &mut tools,
            Stage::Deformation,
            &DetectOptions::default(),
            &mut ws,
            out,
        )
        .expect("a consistent benchmark surface");
    };
    // Warm-up (sizes the workspace and the history); its output is the one
    // compared across methods.
    run(&mut hist, first);
    let mut out = first.clone();
    let start = Instant::now();
    let mut n = 0;
    while n < opts.min_repeats || start.elapsed() < opts.min_time {
        run(&mut hist, &mut out);
        n += 1;
    }
    (start.elapsed().as_secs_f64() * 1e3 / n as f64, n)
}

/// Runs the benchmark on a surface (positions in m, outward triangles).
pub fn run_collision_bench(
    surface_positions: &[Point3<f64>],
    triangles: &[[u32; 3]],
    opts: &BenchOptions,
) -> Vec<Row> {
    let to_volume: Vec<u32> = (0..surface_positions.len() as u32).collect();
    let poses = touching_poses(surface_positions, opts.spatulas);
    let mut rows = Vec::new();
    let mut bvh = match Bvh::new(triangles, surface_positions) {
        Ok(b) => b,
        Err(e) => {
            tracing::error!("benchmark surface rejected: {e}");
            return rows;
        }
    };
    let mut brute = opts
        .brute
        .then(|| BruteForce::new(triangles, surface_positions).ok())
        .flatten();
    for &npf in &opts.nodes_per_face {
        let Ok(inst) = Instrument::new(
            Plate::flat(1e-3, 0.01, PLATE_LENGTH),
            NodeLayout::WholeFace { per_face: npf },
            None,
        ) else {
            continue;
        };
        let rays = inst.len() * poses.len();
        let row = |method: &str, ms: f64, repeats: usize, pairs: usize| Row {
            method: method.into(),
            backend: "cpu".into(),
            triangles: triangles.len(),
            nodes_per_face: npf,
            spatulas: poses.len(),
            rays,
            ms_per_query: ms,
            repeats,
            pairs,
            speedup: None,
            matches_brute: None,
        };
        let mut out_bvh = ContactOutput::default();
        let (ms_bvh, rep_bvh) = time_queries(
            &mut bvh,
            surface_positions,
            triangles,
            &to_volume,
            &inst,
            &poses,
            opts,
            &mut out_bvh,
        );
        let mut bvh_row = row("bvh", ms_bvh, rep_bvh, out_bvh.pairs.len());
        if let Some(brute) = brute.as_mut() {
            let mut out_brute = ContactOutput::default();
            let (ms, rep) = time_queries(
                brute,
                surface_positions,
                triangles,
                &to_volume,
                &inst,
                &poses,
                opts,
                &mut out_brute,
            );
            let mut r = row("brute", ms, rep, out_brute.pairs.len());
            r.speedup = Some(1.0);
            r.matches_brute = Some(true);
            bvh_row.speedup = Some(ms / ms_bvh);
            bvh_row.matches_brute = Some(out_brute == out_bvh);
            rows.push(r);
        }
        rows.push(bvh_row);
    }
    rows
}

/// Prints rows as a table, or as JSON (an array of rows).
pub fn print(rows: &[Row], json: bool) {
    if json {
        match serde_json::to_string_pretty(rows) {
            Ok(s) => println!("{s}"),
            Err(e) => tracing::error!("cannot serialise rows: {e}"),
        }
        return;
    }
    println!(
        "{:<6} {:<4} {:>9} {:>6} {:>4} {:>6} {:>12} {:>7} {:>6} {:>9} {:>6}",
        "method",
        "dev",
        "triangles",
        "nodes",
        "spat",
        "rays",
        "ms/query",
        "repeats",
        "pairs",
        "speedup",
        "same"
    );
    for r in rows {
        println!(
            "{:<6} {:<4} {:>9} {:>6} {:>4} {:>6} {:>12.4} {:>7} {:>6} {:>9} {:>6}",
            r.method,
            r.backend,
            r.triangles,
            r.nodes_per_face,
            r.spatulas,
            r.rays,
            r.ms_per_query,
            r.repeats,
            r.pairs,
            r.speedup.map_or("-".into(), |s| format!("{s:.1}x")),
            r.matches_brute.map_or("-".into(), |m| m.to_string()),
        );
    }
}

/// The benchmark surface of our own measurements: the boundary of a
/// 150 x 120 x 100 mm box with 45 x 36 x 29 cells, 15,876 triangles (the
/// paper's phantom has 15,865).
pub fn paper_sized_box() -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let mesh = fissure_server::mesh::blocks::cuboid([0.15, 0.12, 0.1], [45, 36, 29]);
    let s = mesh.boundary();
    let mut pos = Vec::new();
    s.gather(&mesh.nodes, &mut pos);
    (pos, s.triangles)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a small block the two methods find the same pairs and both rows
    /// come out for every node count.
    #[test]
    fn rows_side_by_side_and_methods_agree() {
        let mesh = fissure_server::mesh::blocks::cuboid([0.06, 0.04, 0.03], [8, 6, 5]);
        let s = mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&mesh.nodes, &mut pos);
        let opts = BenchOptions {
            nodes_per_face: vec![30, 150],
            min_time: Duration::from_millis(1),
            min_repeats: 2,
            ..BenchOptions::default()
        };
        let rows = run_collision_bench(&pos, &s.triangles, &opts);
        assert_eq!(rows.len(), 4);
        for pair in rows.chunks(2) {
            assert_eq!(pair[0].method, "brute");
            assert_eq!(pair[1].method, "bvh");
            assert_eq!(pair[1].matches_brute, Some(true));
            assert!(pair[1].pairs > 0, "the spatulas touch the surface");
            assert_eq!(pair[1].rays, 2 * 2 * pair[1].nodes_per_face);
            assert!(pair[1].speedup.is_some_and(|s| s > 0.0));
        }
        print(&rows, false);
        print(&rows, true);
    }

    /// The full benchmark at the paper's size; run with
    /// `RAYON_NUM_THREADS=1 cargo test --release -p fissure-cli bench_collision -- --ignored --nocapture`.
    #[test]
    #[ignore = "benchmark: seconds in release, minutes in debug"]
    fn paper_size_benchmark() {
        let (pos, tris) = paper_sized_box();
        assert_eq!(tris.len(), 15_876);
        let rows = run_collision_bench(&pos, &tris, &BenchOptions::default());
        // Refit alone, for the breakdown of the BVH rows.
        let mut bvh = Bvh::new(&tris, &pos).unwrap();
        let start = Instant::now();
        for _ in 0..200 {
            bvh.update_positions(&pos);
        }
        println!(
            "bvh refit alone: {:.4} ms",
            start.elapsed().as_secs_f64() * 1e3 / 200.0
        );
        print(&rows, false);
        print(&rows, true);
    }
}
