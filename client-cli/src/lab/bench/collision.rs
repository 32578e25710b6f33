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
//! at least [`fissure_engine::collide::rays::bvh::BUNDLE_MIN`] parallel rays (the
//! server's default, `Traversal::Bundled`); the `bvh-per-ray` rows beside
//! them walk it once per ray, in the same run.
//!
//! The refit alone is reported for three position changes: none (the force
//! loop between two published surfaces), local (the bump) and global (every
//! vertex moved).
//!
//! # Placements
//! `aligned` is the placement above: the spatulas' node grids share
//! coordinates with the surface's lattice planes, so many rays pass exactly
//! through shared edges and vertices (ties of the watertight test). `offset`
//! moves both spatulas within their plate plane by [`OFFSET_FRACTIONS`] of the
//! lattice spacing (width, length), as a real scene is not aligned with the
//! mesh. `--placement both` (the default) runs both, one report each.
//!
//! # Ray files
//! `--dump-rays DIR` writes, per placement and node count, the rays of one
//! deformation-stage query (bounded, as the server casts them) with the
//! surface and the BVH's answers ([`crate::lab::bench::rays`]), for
//! `fissure bench rays` and the Embree comparison to cast again.
//!
//! Rayon uses its global pool: run with `RAYON_NUM_THREADS=1` (and
//! `taskset -c 0`) for one core.

use anyhow::Context;
use fissure_engine::collide::rays::bvh::Traversal;
use fissure_engine::collide::rays::gpu::{GpuBruteForce, GpuBvh};
use fissure_engine::collide::{
    BruteForce, Bvh, ContactOutput, ContactQuery, DetectOptions, FissurePlacement, History,
    HistoryMode, Instrument, NodeHits, NodeLayout, Plate, RayBackend, RayRange, Stage, Tool,
    Workspace, detect_many,
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
/// The `offset` placement's shift of both spatulas within their plate plane,
/// as fractions of the surface's lattice spacing: along the width, along the
/// length (irrational-looking, so that no node lands on a lattice plane).
pub const OFFSET_FRACTIONS: [f64; 2] = [0.372, 0.618];

/// Where the spatulas lie against the surface's lattice.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Placement {
    /// Node grids on the lattice planes (ties on shared edges and vertices).
    Aligned,
    /// Node grids shifted off the lattice by [`OFFSET_FRACTIONS`].
    Offset,
}

impl Placement {
    /// The name in reports and file names.
    pub fn name(self) -> &'static str {
        match self {
            Self::Aligned => "aligned",
            Self::Offset => "offset",
        }
    }
}

/// Which placements to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PlacementChoice {
    /// The aligned placement only.
    Aligned,
    /// The offset placement only.
    Offset,
    /// Both, one report each.
    Both,
}

impl PlacementChoice {
    /// The placements to run, in order.
    pub fn placements(self) -> Vec<Placement> {
        match self {
            Self::Aligned => vec![Placement::Aligned],
            Self::Offset => vec![Placement::Offset],
            Self::Both => vec![Placement::Aligned, Placement::Offset],
        }
    }
}

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
    #[arg(long, default_value_t = fissure_engine::scene::DEFAULT_MAX_DEPTH_M)]
    pub max_depth_m: f64,
    /// Spatulas on the lattice, shifted off it, or both (one report each).
    #[arg(long, value_enum, default_value_t = PlacementChoice::Both)]
    pub placement: PlacementChoice,
    /// Write the rays of one query per placement and node count into this
    /// directory (`<surface>-<placement>-<nodes>.rays`, read by
    /// `fissure bench rays` and the Embree comparison).
    #[arg(long, value_name = "DIR")]
    pub dump_rays: Option<std::path::PathBuf>,
    /// Print JSON (one report per placement, in an array) instead of a table.
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
            max_depth_m: fissure_engine::scene::DEFAULT_MAX_DEPTH_M,
        }
    }
}

/// The surface and the spatulas of a run.
#[derive(Debug, Clone)]
pub struct BenchSurface {
    /// "phantom:<preset>" or "cuboid".
    pub name: String,
    /// "aligned", "offset", or a caller's name.
    pub placement: String,
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
            placement: Placement::Aligned.name().into(),
            rest,
            deformed,
            triangles,
            poses,
        }
    }

    /// The surface with its spatulas placed as `placement` on a lattice of
    /// spacing `spacing_m` (module documentation).
    fn placed(
        name: String,
        rest: Vec<Point3<f64>>,
        triangles: Vec<[u32; 3]>,
        poses: Vec<Isometry3<f64>>,
        placement: Placement,
        spacing_m: f64,
    ) -> Self {
        let poses = match placement {
            Placement::Aligned => poses,
            Placement::Offset => {
                let [w, l] = OFFSET_FRACTIONS.map(|f| f * spacing_m);
                poses
                    .into_iter()
                    .map(|p| {
                        // Instrument y is the width, z the length.
                        let shift = p.rotation * Vector3::new(0.0, w, l);
                        Isometry3::from_parts(
                            Translation3::from(p.translation.vector + shift),
                            p.rotation,
                        )
                    })
                    .collect()
            }
        };
        let mut s = Self::new(name, rest, triangles, poses);
        s.placement = placement.name().into();
        s
    }

    /// The boundary of phantom preset `preset`, two spatulas in the left
    /// Sylvian fissure (module documentation), placed as `placement`.
    pub fn phantom(preset: &str, placement: Placement) -> anyhow::Result<Self> {
        let spacing = fissure_engine::mesh::phantom::preset_params(preset)
            .with_context(|| format!("phantom preset {preset:?}"))?
            .spacing;
        let phantom = fissure_engine::mesh::phantom::preset(preset)
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
        Ok(Self::placed(
            format!("phantom:{preset}"),
            pos,
            s.triangles,
            poses,
            placement,
            spacing,
        ))
    }

    /// The box of the paper's size, two spatulas on its top face, placed as
    /// `placement` (its cells are [`BOX_SIZE_M`] / [`BOX_CELLS`]; the shift
    /// uses the cell length along the plates' width).
    pub fn cuboid(placement: Placement) -> Self {
        let (pos, tris) = paper_sized_box();
        let poses = touching_poses(&pos, 2);
        let spacing = BOX_SIZE_M[1] / BOX_CELLS[1] as f64;
        Self::placed("cuboid".into(), pos, tris, poses, placement, spacing)
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
    /// Placement of the spatulas ("aligned" or "offset").
    pub placement: String,
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

/// One history per spatula, as a new session starts.
fn fresh_histories(surf: &BenchSurface, inst: &Instrument) -> Vec<History> {
    surf.poses
        .iter()
        .map(|_| History::new(inst, HistoryMode::ForceRate))
        .collect()
}

/// The benchmark's instrument: a flat plate of [`PLATE`] with `per_face`
/// nodes a face, reach capped at `max_depth_m`.
fn bench_instrument(per_face: usize, max_depth_m: f64) -> anyhow::Result<Instrument> {
    let mut inst = Instrument::new(
        Plate::flat(PLATE[0], PLATE[1], PLATE[2]),
        NodeLayout::WholeFace { per_face },
        None,
    )
    .with_context(|| format!("{per_face} nodes a face"))?;
    inst.cap_reach(max_depth_m);
    Ok(inst)
}

/// Every vertex moved by about a micrometre (a global refit).
fn global_move(rest: &[Point3<f64>]) -> Vec<Point3<f64>> {
    rest.iter()
        .map(|p| p + Vector3::new(1e-6, -1e-6, 1e-6))
        .collect()
}

/// One deformation-stage query of all spatulas at `positions`: the update
/// (a BVH refits) and [`detect_many`].
#[allow(clippy::too_many_arguments)]
fn query(
    backend: &mut dyn RayBackend,
    surf: &BenchSurface,
    positions: &[Point3<f64>],
    to_volume: &[u32],
    inst: &Instrument,
    hist: &mut [History],
    detect: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) {
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
        ws,
        out,
    )
    .expect("a consistent benchmark surface");
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
    let mut hist = fresh_histories(surf, inst);
    let mut ws = Workspace::new();
    let mut run = |k: usize, hist: &mut [History], out: &mut ContactOutput| {
        let positions = if k % 2 == 0 {
            &surf.rest
        } else {
            &surf.deformed
        };
        query(
            backend, surf, positions, to_volume, inst, hist, detect, &mut ws, out,
        );
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

/// Mean time of `update_positions` alternating `a` and `b` (at least 20
/// and `min`), ms.
pub(crate) fn time_refit(
    bvh: &mut Bvh,
    a: &[Point3<f64>],
    b: &[Point3<f64>],
    min: Duration,
) -> f64 {
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
        placement: surf.placement.clone(),
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
        let inst = bench_instrument(npf, opts.max_depth_m)?;
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
        let global = global_move(&surf.rest);
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

/// A backend that casts with a BVH and keeps every ray it was asked, with
/// its range and answer (the recorder of `--dump-rays`).
struct Recorder<'a> {
    bvh: &'a mut Bvh,
    origins: Vec<Point3<f64>>,
    dirs: Vec<Vector3<f64>>,
    ranges: Vec<RayRange>,
    answers: Vec<NodeHits>,
}

impl RayBackend for Recorder<'_> {
    fn method(&self) -> &'static str {
        self.bvh.method()
    }
    fn backend(&self) -> &'static str {
        self.bvh.backend()
    }
    fn update_positions(&mut self, positions: &[Point3<f64>]) {
        self.bvh.update_positions(positions);
    }
    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let line = vec![RayRange::LINE; origins.len()];
        self.cast_ranged(origins, dirs, &line, out);
    }
    fn cast_ranged(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        out: &mut Vec<NodeHits>,
    ) {
        self.bvh.cast_ranged(origins, dirs, ranges, out);
        self.origins.extend_from_slice(origins);
        self.dirs.extend_from_slice(dirs);
        self.ranges.extend_from_slice(ranges);
        self.answers.extend_from_slice(out);
    }
}

/// The rays of one deformation-stage query on the rest surface, bounded as
/// the server casts them, for every node count of `opts`, written into
/// `dir`; returns the files.
pub fn dump_rays(
    surf: &BenchSurface,
    opts: &BenchOptions,
    dir: &std::path::Path,
) -> anyhow::Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let to_volume: Vec<u32> = (0..surf.rest.len() as u32).collect();
    let mut bvh = Bvh::new(&surf.triangles, &surf.rest).context("benchmark surface")?;
    let moved = global_move(&surf.rest);
    let mut files = Vec::new();
    for &npf in &opts.nodes_per_face {
        let inst = bench_instrument(npf, opts.max_depth_m)?;
        let mut rec = Recorder {
            bvh: &mut bvh,
            origins: Vec::new(),
            dirs: Vec::new(),
            ranges: Vec::new(),
            answers: Vec::new(),
        };
        let mut hist = fresh_histories(surf, &inst);
        query(
            &mut rec,
            surf,
            &surf.rest,
            &to_volume,
            &inst,
            &mut hist,
            &DetectOptions::default(),
            &mut Workspace::new(),
            &mut ContactOutput::default(),
        );
        let file = crate::lab::bench::rays::RayFile {
            rest: surf.rest.clone(),
            deformed: surf.deformed.clone(),
            moved: moved.clone(),
            triangles: surf.triangles.clone(),
            origins: rec.origins,
            dirs: rec.dirs,
            ranges: rec.ranges,
            answers: rec.answers,
        };
        let name = format!(
            "{}-{}-{npf}.rays",
            surf.name.replace([':', '/'], "-"),
            surf.placement
        );
        let path = dir.join(name);
        file.write(&path)?;
        files.push(path);
    }
    Ok(files)
}

/// `fissure bench collision`: builds the surface, runs, prints.
pub fn run(args: &CollisionArgs) -> anyhow::Result<()> {
    let opts = BenchOptions {
        nodes_per_face: args.nodes.clone(),
        cpu: args.backend != BackendChoice::Gpu,
        gpu: args.backend != BackendChoice::Cpu,
        min_time: Duration::from_millis(args.min_time_ms),
        min_repeats: args.min_repeats.max(1),
        max_depth_m: args.max_depth_m,
    };
    let mut reports = Vec::new();
    for placement in args.placement.placements() {
        let surf = match args.surface {
            SurfaceKind::Phantom => BenchSurface::phantom(&args.preset, placement)?,
            SurfaceKind::Cuboid => BenchSurface::cuboid(placement),
        };
        if let Some(dir) = &args.dump_rays {
            for f in dump_rays(&surf, &opts, dir)? {
                eprintln!("wrote {}", f.display());
            }
        }
        let report = run_collision_bench(&surf, &opts)?;
        if !args.json {
            print(&report, false);
            println!();
        }
        reports.push(report);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    }
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
        "surface {} ({} triangles), placement {}, {} rayon thread(s)",
        report.surface, report.triangles, report.placement, report.threads
    );
    match (&report.adapter, &report.gpu_error) {
        (Some(a), _) => println!("GPU adapter: {a}"),
        (None, Some(e)) => println!("no GPU rows: {e}"),
        (None, None) => {}
    }
    println!(
        "{:<11} {:<4} {:<7} {:>9} {:>6} {:>4} {:>6} {:>12} {:>7} {:>6} {:>9} {:>6}",
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
            "{:<11} {:<4} {:<7} {:>9} {:>6} {:>4} {:>6} {:>12.4} {:>7} {:>6} {:>9} {:>6}",
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

/// Size of the benchmark's box, m.
pub const BOX_SIZE_M: [f64; 3] = [0.15, 0.12, 0.1];
/// Cells of the benchmark's box along x, y, z.
pub const BOX_CELLS: [usize; 3] = [45, 36, 29];

/// The benchmark's box: the boundary of a 150 x 120 x 100 mm box with
/// 45 x 36 x 29 cells, 15,876 triangles (the paper's phantom has 15,865).
pub fn paper_sized_box() -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let mesh = fissure_engine::mesh::blocks::cuboid(BOX_SIZE_M, BOX_CELLS);
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
        let mesh = fissure_engine::mesh::blocks::cuboid([0.06, 0.04, 0.03], [8, 6, 5]);
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
        for placement in [Placement::Aligned, Placement::Offset] {
            let surf = BenchSurface::phantom("coarse", placement).unwrap();
            let report = run_collision_bench(&surf, &quick()).unwrap();
            assert_eq!(report.placement, placement.name());
            check_rows(&report);
        }
    }

    /// The offset placement moves the spatulas off the lattice within their
    /// plate plane: same plate normal, same depth into the wall.
    #[test]
    fn offset_placement_shifts_the_plates_within_their_plane() {
        let a = BenchSurface::phantom("coarse", Placement::Aligned).unwrap();
        let b = BenchSurface::phantom("coarse", Placement::Offset).unwrap();
        let h = fissure_engine::mesh::phantom::preset_params("coarse")
            .unwrap()
            .spacing;
        for (p, q) in a.poses.iter().zip(&b.poses) {
            assert_eq!(p.rotation, q.rotation);
            let d = p.rotation.inverse() * (q.translation.vector - p.translation.vector);
            assert!(d.x.abs() < 1e-15, "no move along the plate normal: {d}");
            assert!((d.y - OFFSET_FRACTIONS[0] * h).abs() < 1e-12);
            assert!((d.z - OFFSET_FRACTIONS[1] * h).abs() < 1e-12);
        }
    }

    /// The dumped rays are the query's rays: the file reads back, fissure's
    /// BVH gives its answers, and it holds every node of both spatulas.
    #[test]
    fn dumped_rays_read_back_with_the_bvh_answers() {
        let surf = BenchSurface::cuboid(Placement::Offset);
        let dir = tempfile::tempdir().unwrap();
        let opts = BenchOptions {
            nodes_per_face: vec![30],
            ..quick()
        };
        let files = dump_rays(&surf, &opts, dir.path()).unwrap();
        assert_eq!(files.len(), 1);
        assert!(files[0].ends_with("cuboid-offset-30.rays"), "{files:?}");
        let f = crate::lab::bench::rays::RayFile::read(&files[0]).unwrap();
        assert!(f.origins.len() >= 2 * 2 * 30, "{}", f.origins.len());
        assert!(
            f.answers
                .iter()
                .any(|a| a.behind.is_some() || a.front.is_some())
        );
        let r = crate::lab::bench::rays::bench_file(&f, "x", Duration::from_millis(1)).unwrap();
        assert_eq!(r.same_answers, r.rays);
    }
}
