//! Collision-query benchmark: the paper's brute force against the refitted BVH,
//! on the CPU and on the GPU, timed side by side in one run (DESIGN.md
//! section 7).
//!
//! # Surfaces
//! * `phantom` (default): the boundary of a brain-phantom preset (`paper-48k`:
//!   14.2k triangles). Two spatulas (flat, 1 x 8 x 30 mm, as in the `sylvian`
//!   scene) lie in the left Sylvian fissure, placed from the landmarks: plate
//!   plane parallel to the fissure's mid-plane, tips 15 mm past the entry,
//!   centre lines 8 mm either side of the entry along the fissure, face A
//!   pushed 0.5 mm into the wall at `+width / 2` (so there is contact).
//! * `cuboid`: the boundary of a 150 x 120 x 100 mm box of the paper's size
//!   (15,876 triangles; the paper's phantom has 15,865), the same plates lying
//!   flat on its top face, face B 0.5 mm into the tissue.
//!
//! # One query
//! What a deformation step asks of the collision stage for all spatulas:
//! `update_positions` (the BVH refits here, the brute force copies) followed by
//! [`detect_many`] (rays, pairs, culling, enforced displacements). Queries
//! alternate between the rest surface and a *deformed* one, so every query's
//! refit has real work: the deformed surface moves the vertices within
//! [`BUMP_RADIUS`] of the spatulas' centre along face A's normal by
//! `BUMP_DEPTH (1 - (r / R)^2)^2` (a smooth local bump, the shape of a
//! deformation local to the fissure). `ms_per_query` is the mean wall time; the
//! speedup of a row is the CPU brute-force time of the same configuration over
//! its own, measured in the same run.
//!
//! # Rays
//! Every node's reach is capped at `--max-depth-m` (the scenes'
//! `collision.max_depth_m`, default 10 mm), as the server does. Rows marked
//! `bounded` cast each line only as far as an answer can matter
//! ([`DetectOptions::bounded_rays`], the server's default); the CPU BVH is also
//! timed casting whole lines (`line`, the paper's pass). Both give the same
//! output (`same`). The CPU BVH rows (`bvh`) walk the tree once per run of
//! at least [`fissure_server::collide::bvh::BUNDLE_MIN`] parallel rays (the
//! server's default, `Traversal::Bundled`); the `bvh-per-ray` rows beside
//! them walk it once per ray, in the same run.
//!
//! The refit alone is reported for three position changes: none (the force
//! loop between two published surfaces), local (the bump) and global (every
//! vertex moved).
//!
//! Rayon uses its global pool: run with `RAYON_NUM_THREADS=1` (and
//! `taskset -c 0`) for one core.

use anyhow::Context;
use fissure_server::collide::bvh::Traversal;
use fissure_server::collide::gpu::{GpuBruteForce, GpuBvh};
use fissure_server::collide::{
    BruteForce, Bvh, ContactOutput, ContactQuery, DetectOptions, FissurePlacement, History,
    HistoryMode, Instrument, NodeLayout, Plate, RayBackend, Stage, Tool, Workspace, detect_many,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::time::{Duration, Instant};

/// Plate of the benchmark (the `sylvian` scene's): thickness, width, length, m.
pub const PLATE: [f64; 3] = [0.001, 0.008, 0.030];
/// Radius of the deformation bump, m.
pub const BUMP_RADIUS: f64 = 0.015;
/// Largest displacement of the deformation bump, m.
pub const BUMP_DEPTH: f64 = 2e-4;
/// Penetration of the pushing face into the tissue, m.
pub const PUSH: f64 = 5e-4;

/// Which surface to run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SurfaceKind {
    /// A brain-phantom preset, spatulas in the left Sylvian fissure.
    Phantom,
    /// A box of the paper's size, spatulas on its top face.
    Cuboid,
}

/// Which devices to run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendChoice {
    /// CPU rows only.
    Cpu,
    /// GPU rows (and the CPU brute force they are compared with).
    Gpu,
    /// CPU and GPU rows.
    All,
}

/// Arguments of `fissure bench collision`.
#[derive(Debug, Clone, clap::Args)]
pub struct CollisionArgs {
    /// Surface: a phantom preset's boundary or a box of the paper's size.
    #[arg(long, value_enum, default_value_t = SurfaceKind::Phantom)]
    pub surface: SurfaceKind,
    /// Phantom preset (coarse, paper-34k, paper-48k), with `--surface phantom`.
    #[arg(long, default_value = "paper-48k")]
    pub preset: String,
    /// Devices to run on.
    #[arg(long, value_enum, default_value_t = BackendChoice::All)]
    pub backend: BackendChoice,
    /// Source nodes per face.
    #[arg(long, value_delimiter = ',', default_values_t = [30usize, 150, 500])]
    pub nodes: Vec<usize>,
    /// Least time spent per row, ms.
    #[arg(long, default_value_t = 500)]
    pub min_time_ms: u64,
    /// Least number of timed queries per row.
    #[arg(long, default_value_t = 3)]
    pub min_repeats: usize,
    /// Reach of the source nodes, m (the scenes' `collision.max_depth_m`).
    #[arg(long, default_value_t = fissure_server::scene::DEFAULT_MAX_DEPTH_M)]
    pub max_depth_m: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchOptions {
    /// Face-node counts per face to measure.
    pub nodes_per_face: Vec<usize>,
    /// CPU rows.
    pub cpu: bool,
    /// GPU rows (when an adapter exists).
    pub gpu: bool,
    /// Least time spent per row; at least `min_repeats` queries are timed.
    pub min_time: Duration,
    /// Least number of timed queries per row.
    pub min_repeats: usize,
    /// Reach of the source nodes, m.
    pub max_depth_m: f64,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            nodes_per_face: vec![30, 150, 500],
            cpu: true,
            gpu: true,
            min_time: Duration::from_millis(500),
            min_repeats: 3,
            max_depth_m: fissure_server::scene::DEFAULT_MAX_DEPTH_M,
        }
    }
}

/// The surface and the spatulas of a run.
#[derive(Debug, Clone)]
pub struct BenchSurface {
    /// "phantom:<preset>" or "cuboid".
    pub name: String,
    /// Rest positions, m.
    pub rest: Vec<Point3<f64>>,
    /// The locally deformed positions (module documentation), m.
    pub deformed: Vec<Point3<f64>>,
    /// Outward triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Spatula poses (instrument frame -> surface frame).
    pub poses: Vec<Isometry3<f64>>,
}

impl BenchSurface {
    /// A surface with `poses`; the deformed positions are made here.
    pub fn new(
        name: String,
        rest: Vec<Point3<f64>>,
        triangles: Vec<[u32; 3]>,
        poses: Vec<Isometry3<f64>>,
    ) -> Self {
        let mid = PLATE[2] * 0.5;
        let n = poses.len().max(1) as f64;
        let centre = poses.iter().fold(Vector3::zeros(), |c, p| {
            c + (p * Point3::new(0.0, 0.0, mid)).coords
        }) / n;
        let normal = poses.first().map_or(Vector3::z(), |p| p * Vector3::x());
        let deformed = rest
            .iter()
            .map(|p| {
                let r2 = (p.coords - centre).norm_squared() / (BUMP_RADIUS * BUMP_RADIUS);
                if r2 < 1.0 {
                    p + normal * (BUMP_DEPTH * (1.0 - r2) * (1.0 - r2))
                } else {
                    *p
                }
            })
            .collect();
        Self {
            name,
            rest,
            deformed,
            triangles,
            poses,
        }
    }

    /// The boundary of phantom preset `preset`, two spatulas in the left
    /// Sylvian fissure (module documentation).
    pub fn phantom(preset: &str) -> anyhow::Result<Self> {
        let phantom = fissure_server::mesh::phantom::preset(preset)
            .with_context(|| format!("phantom preset {preset:?}"))?;
        let s = phantom.mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&phantom.mesh.nodes, &mut pos);
        let f = phantom.landmarks.sylvian_left;
        let offset = FissurePlacement::into_wall(&f, PLATE[0], PUSH);
        let poses = [-0.008, 0.008]
            .map(|across| {
                FissurePlacement {
                    insertion: 0.015,
                    across,
                    offset,
                }
                .pose(&f, PLATE[2])
            })
            .to_vec();
        Ok(Self::new(
            format!("phantom:{preset}"),
            pos,
            s.triangles,
            poses,
        ))
    }

    /// The box of the paper's size, two spatulas on its top face.
    pub fn cuboid() -> Self {
        let (pos, tris) = paper_sized_box();
        let poses = touching_poses(&pos, 2);
        Self::new("cuboid".into(), pos, tris, poses)
    }
}

/// One measured configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    /// "brute" or "bvh".
    pub method: String,
    /// "cpu" or "gpu".
    pub backend: String,
    /// Surface triangles.
    pub triangles: usize,
    /// Source nodes per face.
    pub nodes_per_face: usize,
    /// Spatulas in the query.
    pub spatulas: usize,
    /// Rays cast per query (all nodes of all spatulas).
    pub rays: usize,
    /// "bounded" (each line only as far as an answer can matter) or "line"
    /// (whole lines).
    pub cast: String,
    /// Mean wall time of one query (refit/update included), ms.
    pub ms_per_query: f64,
    /// Timed queries.
    pub repeats: usize,
    /// Surviving pairs of the first query (same for every method).
    pub pairs: usize,
    /// CPU brute-force time over this row's time, measured in the same run.
    pub speedup: Option<f64>,
    /// Whether the first query's output (pairs, cancelled pairs, enforced
    /// displacements) equals the CPU brute force's, bit for bit.
    pub matches_brute: Option<bool>,
}

/// The CPU BVH's refit alone, ms per `update_positions`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RefitTimes {
    /// Positions unchanged (one comparison per vertex).
    pub unchanged_ms: f64,
    /// The local bump (module documentation).
    pub local_ms: f64,
    /// Leaves refitted by the local bump.
    pub local_leaves: usize,
    /// Every vertex moved (a full refit).
    pub global_ms: f64,
    /// Leaves in the tree.
    pub leaves: usize,
}

/// Everything one run measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// Surface name.
    pub surface: String,
    /// Surface triangles.
    pub triangles: usize,
    /// Rayon threads the CPU rows ran on.
    pub threads: usize,
    /// GPU adapter of the GPU rows (None: no GPU rows).
    pub adapter: Option<String>,
    /// Why there are no GPU rows, when asked for.
    pub gpu_error: Option<String>,
    /// The rows, per node count: CPU brute, CPU BVH (bundled, then per ray),
    /// GPU brute, GPU BVH, CPU BVH whole lines (per ray, then bundled).
    pub rows: Vec<Row>,
    /// The CPU BVH refit alone.
    pub refit: Option<RefitTimes>,
}

/// Spatula poses touching the surface: plates lying flat on the top of the
/// bounding box, length along +x, face B (normal -z) [`PUSH`] into the tissue,
/// spread along x over the middle of the box.
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
            let x = c.x + 0.3 * ext.x * f - 0.5 * PLATE[2] + 0.37e-3;
            let z = hi.z + 0.5 * PLATE[0] - PUSH;
            Isometry3::from_parts(Translation3::new(x, c.y + 0.11e-3, z), rot)
        })
        .collect()
}

/// Times queries alternating rest and deformed positions; returns (ms per
/// query, queries) and the first query's output in `first`.
fn time_queries(
    backend: &mut dyn RayBackend,
    surf: &BenchSurface,
    to_volume: &[u32],
    inst: &Instrument,
    opts: &BenchOptions,
    detect: &DetectOptions,
    first: &mut ContactOutput,
) -> (f64, usize) {
    let mut hist: Vec<History> = surf
        .poses
        .iter()
        .map(|_| History::new(inst, HistoryMode::ForceRate))
        .collect();
    let mut ws = Workspace::new();
    let mut run = |k: usize, hist: &mut [History], out: &mut ContactOutput| {
        let positions = if k % 2 == 0 {
            &surf.rest
        } else {
            &surf.deformed
        };
        backend.update_positions(positions);
        let query = ContactQuery {
            positions,
            rest: &surf.rest,
            triangles: &surf.triangles,
            to_volume,
            solved: None,
        };
        let mut tools: Vec<Tool<'_>> = hist
            .iter_mut()
            .zip(&surf.poses)
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
            detect,
            &mut ws,
            out,
        )
        .expect("a consistent benchmark surface");
    };
    // Warm-up on the rest surface (sizes the workspace); its output is the one
    // compared across methods.
    run(0, &mut hist, first);
    let mut out = first.clone();
    let start = Instant::now();
    let mut n = 0;
    while n < opts.min_repeats || start.elapsed() < opts.min_time {
        run(n + 1, &mut hist, &mut out);
        n += 1;
    }
    (start.elapsed().as_secs_f64() * 1e3 / n as f64, n)
}

/// Mean time of `update_positions` alternating `a` and `b`, ms.
fn time_refit(bvh: &mut Bvh, a: &[Point3<f64>], b: &[Point3<f64>], min: Duration) -> f64 {
    bvh.update_positions(a);
    let start = Instant::now();
    let mut n = 0;
    while n < 20 || start.elapsed() < min {
        bvh.update_positions(if n % 2 == 0 { b } else { a });
        n += 1;
    }
    start.elapsed().as_secs_f64() * 1e3 / n as f64
}

/// Runs the benchmark on `surf`.
pub fn run_collision_bench(surf: &BenchSurface, opts: &BenchOptions) -> anyhow::Result<Report> {
    let tris = &surf.triangles;
    let to_volume: Vec<u32> = (0..surf.rest.len() as u32).collect();
    let mut report = Report {
        surface: surf.name.clone(),
        triangles: tris.len(),
        threads: rayon::current_num_threads(),
        adapter: None,
        gpu_error: None,
        rows: Vec::new(),
        refit: None,
    };
    let mut brute = BruteForce::new(tris, &surf.rest).context("benchmark surface")?;
    let mut bvh = Bvh::new(tris, &surf.rest).context("benchmark surface")?;
    let (mut gpu_brute, mut gpu_bvh) = (None, None);
    if opts.gpu {
        match GpuBruteForce::try_new(tris, &surf.rest)
            .and_then(|b| Ok((b, GpuBvh::try_new(tris, &surf.rest)?)))
        {
            Ok((b, v)) => {
                report.adapter = Some(format!(
                    "{} ({:?})",
                    b.adapter_name(),
                    b.adapter_info().backend
                ));
                gpu_brute = Some(b);
                gpu_bvh = Some(v);
            }
            Err(e) => report.gpu_error = Some(e.to_string()),
        }
    }
    if opts.max_depth_m.is_nan() || opts.max_depth_m <= 0.0 {
        anyhow::bail!("--max-depth-m must be positive, got {}", opts.max_depth_m);
    }
    let bounded = DetectOptions::default();
    let line = DetectOptions {
        bounded_rays: false,
        ..bounded
    };
    for &npf in &opts.nodes_per_face {
        let mut inst = Instrument::new(
            Plate::flat(PLATE[0], PLATE[1], PLATE[2]),
            NodeLayout::WholeFace { per_face: npf },
            None,
        )
        .with_context(|| format!("{npf} nodes a face"))?;
        inst.cap_reach(opts.max_depth_m);
        let row = |method: &str,
                   backend: &str,
                   detect: &DetectOptions,
                   ms: f64,
                   repeats: usize,
                   pairs: usize| Row {
            method: method.into(),
            backend: backend.into(),
            cast: if detect.bounded_rays {
                "bounded"
            } else {
                "line"
            }
            .into(),
            triangles: tris.len(),
            nodes_per_face: npf,
            spatulas: surf.poses.len(),
            rays: inst.len() * surf.poses.len(),
            ms_per_query: ms,
            repeats,
            pairs,
            speedup: None,
            matches_brute: None,
        };
        // The CPU brute force is the reference of every row.
        let mut reference = ContactOutput::default();
        let (ms_ref, rep) = time_queries(
            &mut brute,
            surf,
            &to_volume,
            &inst,
            opts,
            &line,
            &mut reference,
        );
        let mut rows = vec![row(
            "brute",
            "cpu",
            &line,
            ms_ref,
            rep,
            reference.pairs.len(),
        )];
        let mut others: Vec<(&mut dyn RayBackend, &DetectOptions)> = Vec::new();
        if opts.cpu {
            others.push((&mut bvh, &bounded));
        }
        if let Some(b) = gpu_brute.as_mut() {
            others.push((b, &line));
        }
        if let Some(b) = gpu_bvh.as_mut() {
            others.push((b, &line));
        }
        for (b, detect) in others {
            let mut out = ContactOutput::default();
            let (ms, rep) = time_queries(b, surf, &to_volume, &inst, opts, detect, &mut out);
            let mut r = row(b.method(), b.backend(), detect, ms, rep, out.pairs.len());
            r.matches_brute = Some(out == reference);
            rows.push(r);
        }
        if opts.cpu {
            // The BVH walked once per ray beside the default bundled walk
            // (one walk per run of parallel rays), bounded then whole line;
            // the default's whole-line row comes last.
            let mut per_ray = |detect: &DetectOptions| {
                bvh.set_traversal(Traversal::PerRay);
                let mut out = ContactOutput::default();
                let (ms, rep) =
                    time_queries(&mut bvh, surf, &to_volume, &inst, opts, detect, &mut out);
                bvh.set_traversal(Traversal::Bundled);
                let mut r = row("bvh-per-ray", "cpu", detect, ms, rep, out.pairs.len());
                r.matches_brute = Some(out == reference);
                r
            };
            let bounded_row = per_ray(&bounded);
            let line_row = per_ray(&line);
            rows.insert(2, bounded_row);
            rows.push(line_row);
            let mut out = ContactOutput::default();
            let (ms, rep) = time_queries(&mut bvh, surf, &to_volume, &inst, opts, &line, &mut out);
            let mut r = row("bvh", "cpu", &line, ms, rep, out.pairs.len());
            r.matches_brute = Some(out == reference);
            rows.push(r);
        }
        for r in &mut rows {
            r.speedup = Some(ms_ref / r.ms_per_query);
        }
        rows[0].matches_brute = Some(true);
        report.rows.extend(rows);
    }
    if opts.cpu {
        let global: Vec<Point3<f64>> = surf
            .rest
            .iter()
            .map(|p| p + Vector3::new(1e-6, -1e-6, 1e-6))
            .collect();
        let min = opts.min_time.min(Duration::from_millis(200));
        let unchanged_ms = time_refit(&mut bvh, &surf.rest, &surf.rest, min);
        let local_ms = time_refit(&mut bvh, &surf.rest, &surf.deformed, min);
        let stats = bvh.refit_stats();
        let global_ms = time_refit(&mut bvh, &surf.rest, &global, min);
        report.refit = Some(RefitTimes {
            unchanged_ms,
            local_ms,
            local_leaves: stats.refitted_leaves,
            global_ms,
            leaves: stats.leaves,
        });
    }
    Ok(report)
}

/// `fissure bench collision`: builds the surface, runs, prints.
pub fn run(args: &CollisionArgs) -> anyhow::Result<()> {
    let surf = match args.surface {
        SurfaceKind::Phantom => BenchSurface::phantom(&args.preset)?,
        SurfaceKind::Cuboid => BenchSurface::cuboid(),
    };
    let opts = BenchOptions {
        nodes_per_face: args.nodes.clone(),
        cpu: args.backend != BackendChoice::Gpu,
        gpu: args.backend != BackendChoice::Cpu,
        min_time: Duration::from_millis(args.min_time_ms),
        min_repeats: args.min_repeats.max(1),
        max_depth_m: args.max_depth_m,
    };
    let report = run_collision_bench(&surf, &opts)?;
    print(&report, args.json);
    Ok(())
}

/// Prints a report as a table, or as JSON.
pub fn print(report: &Report, json: bool) {
    if json {
        match serde_json::to_string_pretty(report) {
            Ok(s) => println!("{s}"),
            Err(e) => tracing::error!("cannot serialise the report: {e}"),
        }
        return;
    }
    println!(
        "surface {} ({} triangles), {} rayon thread(s)",
        report.surface, report.triangles, report.threads
    );
    match (&report.adapter, &report.gpu_error) {
        (Some(a), _) => println!("GPU adapter: {a}"),
        (None, Some(e)) => println!("no GPU rows: {e}"),
        (None, None) => {}
    }
    println!(
        "{:<6} {:<4} {:<7} {:>9} {:>6} {:>4} {:>6} {:>12} {:>7} {:>6} {:>9} {:>6}",
        "method",
        "dev",
        "cast",
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
    for r in &report.rows {
        println!(
            "{:<6} {:<4} {:<7} {:>9} {:>6} {:>4} {:>6} {:>12.4} {:>7} {:>6} {:>9} {:>6}",
            r.method,
            r.backend,
            r.cast,
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
    if let Some(f) = &report.refit {
        println!(
            "cpu bvh refit alone: unchanged {:.4} ms, local {:.4} ms ({} of {} leaves), global {:.4} ms",
            f.unchanged_ms, f.local_ms, f.local_leaves, f.leaves, f.global_ms
        );
    }
}

/// The benchmark's box: the boundary of a 150 x 120 x 100 mm box with
/// 45 x 36 x 29 cells, 15,876 triangles (the paper's phantom has 15,865).
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

    fn quick() -> BenchOptions {
        BenchOptions {
            nodes_per_face: vec![30, 150],
            min_time: Duration::from_millis(1),
            min_repeats: 2,
            ..BenchOptions::default()
        }
    }

    fn check_rows(report: &Report) {
        let per = report.rows.len() / 2;
        assert!(per >= 2, "brute and bvh rows for each node count");
        for rows in report.rows.chunks(per) {
            assert_eq!(
                (rows[0].method.as_str(), rows[0].backend.as_str()),
                ("brute", "cpu")
            );
            assert_eq!(
                (
                    rows[1].method.as_str(),
                    rows[1].backend.as_str(),
                    rows[1].cast.as_str()
                ),
                ("bvh", "cpu", "bounded")
            );
            assert_eq!(
                (rows[2].method.as_str(), rows[2].cast.as_str()),
                ("bvh-per-ray", "bounded")
            );
            let last = rows.last().unwrap();
            assert_eq!((last.method.as_str(), last.cast.as_str()), ("bvh", "line"));
            for r in rows {
                assert_eq!(r.matches_brute, Some(true), "{r:?}");
                assert!(r.pairs > 0, "the spatulas touch the surface: {r:?}");
                assert_eq!(r.rays, 2 * 2 * r.nodes_per_face);
                assert!(r.speedup.is_some_and(|s| s > 0.0));
            }
        }
        let refit = report.refit.as_ref().expect("refit times");
        assert!(refit.local_leaves > 0 && refit.local_leaves < refit.leaves);
    }

    /// On a small block the methods find the same contacts and every row
    /// comes out for every node count (GPU rows where an adapter exists).
    #[test]
    fn rows_side_by_side_and_methods_agree() {
        let mesh = fissure_server::mesh::blocks::cuboid([0.06, 0.04, 0.03], [8, 6, 5]);
        let s = mesh.boundary();
        let mut pos = Vec::new();
        s.gather(&mesh.nodes, &mut pos);
        let poses = touching_poses(&pos, 2);
        let surf = BenchSurface::new("block".into(), pos, s.triangles, poses);
        let report = run_collision_bench(&surf, &quick()).unwrap();
        check_rows(&report);
        print(&report, false);
        print(&report, true);
    }

    /// On the coarse phantom the spatulas in the Sylvian fissure touch its
    /// wall, and all methods agree.
    #[test]
    fn phantom_fissure_rows_agree() {
        let surf = BenchSurface::phantom("coarse").unwrap();
        let report = run_collision_bench(&surf, &quick()).unwrap();
        check_rows(&report);
    }
}
