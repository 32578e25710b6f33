//! `fissure mesh ...`: generate, convert and inspect brain-model files.
//!
//! Each subcommand is a library function ([`generate`], [`convert`],
//! [`inspect`]) that returns plain data, so tests call it without a
//! subprocess; [`run`] prints.

use anyhow::{Context, bail};
use fissure_server::mesh::TetMesh;
use fissure_server::mesh::io::{self, SurfaceFormat, VolumeFormat};
use fissure_server::mesh::quality::{Histogram, QualitySummary, tets_quality};
use fissure_server::mesh::validate::{Problem, ValidateOptions, validate, validate_surface};
use std::path::{Path, PathBuf};

/// Mesh tools.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum MeshCommand {
    /// Generate a built-in model and write it (format from the extension:
    /// .vtu, .msh, .vtk, .node/.ele; or .obj, .ply, .stl for its boundary
    /// surface).
    Generate {
        /// Model name: the brain phantom presets `coarse`, `paper-34k`
        /// (about 9.1k nodes / 34k tets), `paper-48k` (about 12.3k / 48k), or
        /// `cube`, `v-valley`, `u-valley` (the paper's test blocks,
        /// 60 x 30 x 30 mm).
        #[arg(long, value_name = "NAME")]
        preset: String,
        /// Output file.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Edge length of the `cube` preset, in metres.
        #[arg(long, value_name = "M", default_value_t = 0.05)]
        size: f64,
        /// Cells per edge of the `cube` preset (each cell is six tetrahedra).
        #[arg(long, value_name = "N", default_value_t = 8)]
        cells: usize,
        /// Mesh a phantom preset with the proven mesher instead: the whole
        /// surface at the fissure spacing, the interior graded, dihedral angles
        /// within the bounds Labelle & Shewchuk prove (8.9 to 158.8 degrees).
        /// About 3 to 4 times the preset's elements (paper-48k: 39.3k nodes,
        /// 204k tetrahedra, 18.3k surface triangles). A fissure narrower than the
        /// spacing may be partly filled (tetrahedra in the gaps: coarse 192,
        /// paper-34k 6, paper-48k none).
        #[arg(long)]
        proven: bool,
    },
    /// Mesh the inside of a closed triangle surface (.obj, .ply, .stl) with
    /// tetrahedra (isosurface stuffing, uniform at the surface and graded
    /// inside, dihedral angles within the proven 8.9 to 158.8 degrees) and
    /// write it (format from the extension). An open, non-manifold or
    /// self-intersecting surface is refused with the offending element named.
    FromSurface {
        /// Closed surface file, positions in metres.
        #[arg(value_name = "FILE")]
        file: PathBuf,
        /// Output volume mesh: .vtu, .msh, .vtk or .node/.ele.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Tetrahedron size at the surface, in metres.
        #[arg(long, value_name = "M", default_value_t = 0.003)]
        resolution: f64,
        /// Grading levels: tetrahedra grow up to 2^levels times the resolution
        /// away from the surface (0: uniform).
        #[arg(long, value_name = "N", default_value_t = 2)]
        levels: u32,
    },
    /// Convert a mesh file to another format (format from the extensions). A
    /// volume mesh written to .obj, .ply or .stl gives its boundary surface.
    Convert {
        /// Input file: .msh (Gmsh 2.2/4.1), .vtk, .vtu, .node/.ele (TetGen),
        /// or a surface .obj, .ply, .stl.
        #[arg(value_name = "IN")]
        input: PathBuf,
        /// Output file: .vtu, .msh (4.1), .vtk, .node/.ele, or a surface
        /// .obj, .ply (binary), .stl (binary), .vtu.
        #[arg(value_name = "OUT")]
        output: PathBuf,
    },
    /// Print counts, bounding box, volume, element quality and problems
    /// (inverted or degenerate tetrahedra, open or non-manifold surface,
    /// duplicate or unused nodes) of a mesh file.
    Inspect {
        /// Volume (.msh, .vtk, .vtu, .node/.ele) or surface (.obj, .ply, .stl) file.
        #[arg(value_name = "FILE")]
        file: PathBuf,
        /// Print one JSON object instead of a table.
        #[arg(long)]
        json: bool,
        /// Nodes closer than this are reported as duplicates, in metres.
        #[arg(long, value_name = "M", default_value_t = 1e-9)]
        duplicate_tolerance: f64,
        /// Number of bins of the quality histograms.
        #[arg(long, value_name = "N", default_value_t = 10)]
        bins: usize,
        /// Problems listed in full (all are counted), at most.
        #[arg(long, value_name = "N", default_value_t = 20)]
        max_listed: usize,
    },
}

/// Runs a mesh subcommand, printing its result to stdout.
pub fn run(cmd: MeshCommand) -> anyhow::Result<()> {
    match cmd {
        MeshCommand::Generate {
            preset,
            out,
            size,
            cells,
            proven,
        } => {
            let mesh = generate(
                &preset,
                &out,
                &PresetOptions {
                    size_m: size,
                    cells,
                    proven,
                },
            )?;
            println!(
                "wrote {}: {} nodes, {} tetrahedra",
                out.display(),
                mesh.nodes.len(),
                mesh.tets.len()
            );
        }
        MeshCommand::FromSurface {
            file,
            out,
            resolution,
            levels,
        } => {
            let mesh = from_surface(&file, resolution, levels)?;
            write_any(&mesh, &out)?;
            println!(
                "wrote {}: {} nodes, {} tetrahedra",
                out.display(),
                mesh.nodes.len(),
                mesh.tets.len()
            );
        }
        MeshCommand::Convert { input, output } => {
            let s = convert(&input, &output)?;
            println!("wrote {}: {s}", output.display());
        }
        MeshCommand::Inspect {
            file,
            json,
            duplicate_tolerance,
            bins,
            max_listed,
        } => {
            let opts = InspectOptions {
                duplicate_tolerance,
                bins,
                max_listed,
            };
            let report = inspect(&file, &opts)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{}", report.table());
            }
        }
    }
    Ok(())
}

/// Reads a closed surface and meshes its inside.
pub fn from_surface(file: &Path, resolution_m: f64, levels: u32) -> anyhow::Result<TetMesh> {
    if !(resolution_m.is_finite() && resolution_m > 0.0) {
        bail!("--resolution must be a positive length in metres, got {resolution_m}");
    }
    let surface = fissure_server::mesh::io::read_surface(file)?;
    let params = fissure_server::mesh::from_surface::SurfaceMeshing {
        spacing: resolution_m,
        levels,
        rate: 0.5,
    };
    fissure_server::mesh::from_surface::mesh_surface(&surface.vertices, &surface.triangles, &params)
        .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))
}

/// Size of the `cube` preset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PresetOptions {
    /// Edge length of the `cube` preset, m.
    pub size_m: f64,
    /// Cells per edge of the `cube` preset.
    pub cells: usize,
    /// Mesh a phantom preset with the proven mesher (surface at the fissure
    /// spacing everywhere, interior graded).
    pub proven: bool,
}

/// The names [`preset_mesh`] knows.
pub const PRESETS: &[&str] = &[
    "coarse",
    "paper-34k",
    "paper-48k",
    "cube",
    "v-valley",
    "u-valley",
];

/// The mesh of a named preset.
pub fn preset_mesh(name: &str, cube: &PresetOptions) -> anyhow::Result<TetMesh> {
    use fissure_server::mesh::blocks;
    // The single list of presets (keep PRESETS in step).
    Ok(match name {
        "coarse" | "paper-34k" | "paper-48k" => {
            fissure_server::mesh::phantom::preset_meshed(name, cube.proven)?.mesh
        }
        "cube" => {
            if !(cube.size_m > 0.0 && cube.size_m.is_finite()) || cube.cells == 0 {
                bail!(
                    "cube: size must be positive (got {} m) and cells at least 1",
                    cube.size_m
                );
            }
            blocks::cube(cube.size_m, cube.cells)
        }
        "v-valley" => blocks::v_valley(),
        "u-valley" => blocks::u_valley(),
        other => bail!("unknown preset '{other}' (known: {})", PRESETS.join(", ")),
    })
}

/// Generates a preset and writes it to `out` (a volume format, or a surface
/// format for its boundary).
pub fn generate(preset: &str, out: &Path, cube: &PresetOptions) -> anyhow::Result<TetMesh> {
    let mesh = preset_mesh(preset, cube)?;
    write_any(&mesh, out)?;
    Ok(mesh)
}

fn write_any(mesh: &TetMesh, out: &Path) -> anyhow::Result<()> {
    if VolumeFormat::from_path(out).is_some() {
        io::write_volume(out, mesh)?;
    } else {
        let b = mesh.boundary();
        let mut v = Vec::new();
        b.gather(&mesh.nodes, &mut v);
        io::write_surface(out, &v, &b.triangles)?;
    }
    Ok(())
}

/// Converts `input` to `output`; returns a one-line summary.
pub fn convert(input: &Path, output: &Path) -> anyhow::Result<String> {
    let out_volume = VolumeFormat::from_path(output).is_some();
    let out_surface = SurfaceFormat::from_path(output).is_some() || out_volume;
    if !out_surface {
        bail!(
            "{}: unknown output format (expected .vtu, .msh, .vtk, .node, .ele, .obj, .ply or .stl)",
            output.display()
        );
    }
    if VolumeFormat::from_path(input).is_some() {
        let r = io::read_volume_report(input)?;
        write_any(&r.mesh, output)?;
        let mut s = format!(
            "{} nodes, {} tetrahedra",
            r.mesh.nodes.len(),
            r.mesh.tets.len()
        );
        for (n, what) in [
            (r.ignored_cells, "other cells skipped"),
            (
                r.higher_order_tets,
                "higher-order tetrahedra reduced to corners",
            ),
            (r.flipped_tets, "tetrahedra reoriented"),
            (r.dropped_nodes, "unused nodes dropped"),
        ] {
            if n > 0 {
                s += &format!(", {n} {what}");
            }
        }
        return Ok(s);
    }
    if SurfaceFormat::from_path(input).is_some() {
        if out_volume
            && !output
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("vtu"))
        {
            bail!(
                "{}: a surface cannot be converted to a volume format; mesh its inside first",
                input.display()
            );
        }
        let s = io::read_surface(input)?;
        io::write_surface(output, &s.vertices, &s.triangles)?;
        return Ok(format!(
            "{} vertices, {} triangles",
            s.vertices.len(),
            s.triangles.len()
        ));
    }
    bail!(
        "{}: unknown input format (expected .msh, .vtk, .vtu, .node, .ele, .obj, .ply or .stl)",
        input.display()
    )
}

/// Options of [`inspect`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InspectOptions {
    /// Duplicate-node distance, m.
    pub duplicate_tolerance: f64,
    /// Histogram bins.
    pub bins: usize,
    /// Problems listed in full.
    pub max_listed: usize,
}

impl Default for InspectOptions {
    fn default() -> Self {
        Self {
            duplicate_tolerance: 1e-9,
            bins: 10,
            max_listed: 20,
        }
    }
}

/// A histogram in a report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HistogramReport {
    /// Lower edge of the first bin.
    pub lo: f64,
    /// Upper edge of the last bin.
    pub hi: f64,
    /// Counts per bin.
    pub counts: Vec<usize>,
}

impl From<Histogram> for HistogramReport {
    fn from(h: Histogram) -> Self {
        Self {
            lo: h.lo,
            hi: h.hi,
            counts: h.counts,
        }
    }
}

/// What `inspect` finds in a file. Quality fields are `None` for surfaces.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Report {
    /// The file inspected.
    pub file: String,
    /// `volume` or `surface`.
    pub kind: &'static str,
    /// Nodes (volume) or vertices (surface) in the file.
    pub nodes: usize,
    /// Tetrahedra kept (0 for a surface).
    pub tets: usize,
    /// Boundary triangles (volume) or triangles (surface).
    pub surface_triangles: usize,
    /// Cells that are not tetrahedra, skipped.
    pub ignored_cells: usize,
    /// Higher-order tetrahedra reduced to their corners.
    pub higher_order_tets: usize,
    /// Tetrahedra negatively oriented in the file (reoriented on load).
    pub flipped_tets: usize,
    /// Axis-aligned bounds of the nodes, m: `[min, max]`.
    pub bounding_box_m: [[f64; 3]; 2],
    /// Sum of the tetrahedron volumes after reorientation, or the volume
    /// enclosed by a surface (divergence theorem), m^3.
    pub volume_m3: f64,
    /// Smallest dihedral angle, degrees.
    pub min_dihedral_deg: Option<f64>,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: Option<f64>,
    /// Smallest radius ratio (1 for a regular tetrahedron).
    pub min_radius_ratio: Option<f64>,
    /// Mean radius ratio.
    pub mean_radius_ratio: Option<f64>,
    /// Radius ratio histogram over [0, 1].
    pub radius_ratio_histogram: Option<HistogramReport>,
    /// Minimum dihedral angle histogram over [0, 90] degrees.
    pub min_dihedral_histogram: Option<HistogramReport>,
    /// Number of problems found (capped at 10,000).
    pub problems_found: usize,
    /// The first problems.
    pub problems: Vec<Problem>,
}

/// Reads a mesh file and reports on it. The tetrahedra are checked as
/// [`io::read_volume`] would load them (negatively oriented ones reoriented)
/// but with every node of the file, so unused nodes show up as problems.
pub fn inspect(path: &Path, opts: &InspectOptions) -> anyhow::Result<Report> {
    let vopts = ValidateOptions {
        duplicate_tolerance: opts.duplicate_tolerance,
        ..Default::default()
    };
    let file = path.display().to_string();
    if VolumeFormat::from_path(path).is_some() {
        let raw = io::read_volume_raw(path)?;
        let mut tets = raw.tets.clone();
        let mut flipped = 0;
        for t in &mut tets {
            let [a, b, c, d] = t.map(|i| raw.nodes[i as usize]);
            if (b - a).cross(&(c - a)).dot(&(d - a)) < 0.0 {
                t.swap(2, 3);
                flipped += 1;
            }
        }
        let problems = validate(&raw.nodes, &tets, &vopts);
        let q = tets_quality(&raw.nodes, &tets);
        let s = QualitySummary::of(&q);
        let mesh = TetMesh {
            nodes: raw.nodes,
            tets,
        };
        let surface_triangles = mesh.boundary().triangles.len();
        let (lo, hi) = mesh.bounds();
        let bins = opts.bins.max(1);
        return Ok(Report {
            file,
            kind: "volume",
            nodes: mesh.nodes.len(),
            tets: mesh.tets.len(),
            surface_triangles,
            ignored_cells: raw.ignored_cells,
            higher_order_tets: raw.higher_order_tets,
            flipped_tets: flipped,
            bounding_box_m: bbox(lo, hi, mesh.nodes.is_empty()),
            volume_m3: s.map_or(0.0, |s| s.total_volume),
            min_dihedral_deg: s.map(|s| s.min_dihedral_deg),
            max_dihedral_deg: s.map(|s| s.max_dihedral_deg),
            min_radius_ratio: s.map(|s| s.min_radius_ratio),
            mean_radius_ratio: s.map(|s| s.mean_radius_ratio),
            radius_ratio_histogram: Some(
                Histogram::new(q.iter().map(|q| q.radius_ratio), 0.0, 1.0, bins).into(),
            ),
            min_dihedral_histogram: Some(
                Histogram::new(q.iter().map(|q| q.min_dihedral_deg), 0.0, 90.0, bins).into(),
            ),
            problems_found: problems.len(),
            problems: problems.into_iter().take(opts.max_listed).collect(),
        });
    }
    if SurfaceFormat::from_path(path).is_some() {
        let s = io::read_surface(path)?;
        let problems = validate_surface(&s.vertices, &s.triangles, &vopts);
        let mesh = TetMesh {
            nodes: s.vertices.clone(),
            tets: Vec::new(),
        };
        let (lo, hi) = mesh.bounds();
        // Enclosed volume: sum over triangles of a . (b x c) / 6.
        let volume: f64 = s
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| s.vertices[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum();
        return Ok(Report {
            file,
            kind: "surface",
            nodes: s.vertices.len(),
            tets: 0,
            surface_triangles: s.triangles.len(),
            ignored_cells: 0,
            higher_order_tets: 0,
            flipped_tets: 0,
            bounding_box_m: bbox(lo, hi, s.vertices.is_empty()),
            volume_m3: volume,
            min_dihedral_deg: None,
            max_dihedral_deg: None,
            min_radius_ratio: None,
            mean_radius_ratio: None,
            radius_ratio_histogram: None,
            min_dihedral_histogram: None,
            problems_found: problems.len(),
            problems: problems.into_iter().take(opts.max_listed).collect(),
        });
    }
    Err(io::IoError::UnknownFormat {
        path: path.to_path_buf(),
        expected: "expected .msh, .vtk, .vtu, .node, .ele, .obj, .ply or .stl",
    })
    .with_context(|| format!("inspecting {}", path.display()))
}

fn bbox(lo: nalgebra::Point3<f64>, hi: nalgebra::Point3<f64>, empty: bool) -> [[f64; 3]; 2] {
    if empty {
        [[0.0; 3]; 2]
    } else {
        [[lo.x, lo.y, lo.z], [hi.x, hi.y, hi.z]]
    }
}

impl Report {
    /// A readable table of the report.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let mut row = |k: &str, v: String| s += &format!("{k:<22} {v}\n");
        row("file", self.file.clone());
        row("kind", self.kind.to_string());
        row("nodes", self.nodes.to_string());
        if self.kind == "volume" {
            row("tetrahedra", self.tets.to_string());
            row("boundary triangles", self.surface_triangles.to_string());
            row("other cells skipped", self.ignored_cells.to_string());
            row("higher-order tets", self.higher_order_tets.to_string());
            row("reoriented tets", self.flipped_tets.to_string());
        } else {
            row("triangles", self.surface_triangles.to_string());
        }
        let [lo, hi] = self.bounding_box_m;
        row(
            "bounding box min (m)",
            format!("{:.6e} {:.6e} {:.6e}", lo[0], lo[1], lo[2]),
        );
        row(
            "bounding box max (m)",
            format!("{:.6e} {:.6e} {:.6e}", hi[0], hi[1], hi[2]),
        );
        row("volume (m^3)", format!("{:.6e}", self.volume_m3));
        if let (Some(a), Some(b)) = (self.min_dihedral_deg, self.max_dihedral_deg) {
            row("dihedral min/max (deg)", format!("{a:.2} / {b:.2}"));
        }
        if let (Some(a), Some(b)) = (self.min_radius_ratio, self.mean_radius_ratio) {
            row("radius ratio min/mean", format!("{a:.4} / {b:.4}"));
        }
        for (name, h) in [
            ("radius ratio", &self.radius_ratio_histogram),
            ("min dihedral (deg)", &self.min_dihedral_histogram),
        ] {
            if let Some(h) = h {
                s += &format!("{name} histogram:\n");
                let n = h.counts.len().max(1);
                let w = (h.hi - h.lo) / n as f64;
                let max = h.counts.iter().copied().max().unwrap_or(0).max(1);
                for (k, c) in h.counts.iter().enumerate() {
                    let bar = "#".repeat((40 * c).div_ceil(max));
                    s += &format!(
                        "  [{:>7.3}, {:>7.3}) {c:>8} {bar}\n",
                        h.lo + k as f64 * w,
                        h.lo + (k + 1) as f64 * w
                    );
                }
            }
        }
        s += &format!("problems: {}\n", self.problems_found);
        for p in &self.problems {
            s += &format!("  {p}\n");
        }
        if self.problems_found > self.problems.len() {
            s += &format!("  ... {} more\n", self.problems_found - self.problems.len());
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed sphere surface written as OBJ meshes to its volume (within the
    /// discretisation error of a 3 mm lattice on a 20 mm sphere); an open
    /// surface is refused naming the open edge.
    #[test]
    fn from_surface_meshes_a_closed_sphere_and_refuses_an_open_one() {
        use fissure_server::mesh::{io, winding::icosphere};
        let dir = tempfile::tempdir().unwrap();
        let (v, t) = icosphere(nalgebra::Point3::origin(), 0.02, 3);
        let obj = dir.path().join("sphere.obj");
        io::write_surface(&obj, &v, &t).unwrap();
        let mesh = from_surface(&obj, 0.003, 1).unwrap();
        let volume: f64 = (0..mesh.tets.len()).map(|e| mesh.signed_volume(e)).sum();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.02f64.powi(3);
        assert!(
            (volume / exact - 1.0).abs() < 0.05,
            "volume {volume} vs {exact}"
        );
        assert!(
            mesh.tets
                .iter()
                .enumerate()
                .all(|(e, _)| mesh.signed_volume(e) > 0.0)
        );
        let open = dir.path().join("open.obj");
        io::write_surface(&open, &v, &t[1..]).unwrap();
        let err = from_surface(&open, 0.003, 1).unwrap_err().to_string();
        assert!(err.contains("open.obj") && err.contains("edge"), "{err}");
        assert!(from_surface(&obj, -1.0, 0).is_err());
    }

    #[test]
    fn a_proven_phantom_has_its_angles_within_the_proven_bounds() {
        use fissure_server::mesh::stuffing::{PROVEN_MAX_DIHEDRAL_DEG, PROVEN_MIN_DIHEDRAL_DEG};
        let dir = tempfile::tempdir().unwrap();
        let vtu = dir.path().join("p.vtu");
        let opts = |proven| PresetOptions {
            size_m: 0.05,
            cells: 8,
            proven,
        };
        let proven = generate("coarse", &vtu, &opts(true)).unwrap();
        let plain = preset_mesh("coarse", &opts(false)).unwrap();
        assert_ne!(proven.tets.len(), plain.tets.len());
        let r = inspect(&vtu, &InspectOptions::default()).unwrap();
        assert_eq!(r.tets, proven.tets.len());
        let (lo, hi) = (r.min_dihedral_deg.unwrap(), r.max_dihedral_deg.unwrap());
        assert!(
            lo >= PROVEN_MIN_DIHEDRAL_DEG && hi <= PROVEN_MAX_DIHEDRAL_DEG,
            "{lo} .. {hi}"
        );
    }

    #[test]
    fn generate_convert_inspect() {
        let dir = tempfile::tempdir().unwrap();
        let vtu = dir.path().join("v.vtu");
        let mesh = generate(
            "v-valley",
            &vtu,
            &PresetOptions {
                size_m: 0.05,
                cells: 8,
                proven: false,
            },
        )
        .unwrap();
        assert_eq!(mesh.tets.len(), 4608);

        let msh = dir.path().join("v.msh");
        let summary = convert(&vtu, &msh).unwrap();
        assert!(
            summary.starts_with(&format!("{} nodes, 4608 tetrahedra", mesh.nodes.len())),
            "{summary}"
        );
        let stl = dir.path().join("v.stl");
        convert(&msh, &stl).unwrap();

        let r = inspect(&msh, &InspectOptions::default()).unwrap();
        assert_eq!(
            (r.nodes, r.tets, r.surface_triangles),
            (mesh.nodes.len(), 4608, 1088)
        );
        assert_eq!(r.problems_found, 0);
        let expect: f64 = (0..mesh.tets.len()).map(|t| mesh.signed_volume(t)).sum();
        assert!((r.volume_m3 - expect).abs() < 1e-15);
        assert_eq!(
            r.radius_ratio_histogram
                .as_ref()
                .unwrap()
                .counts
                .iter()
                .sum::<usize>(),
            4608
        );
        let json: serde_json::Value = serde_json::to_value(&r).unwrap();
        for key in [
            "nodes",
            "tets",
            "surface_triangles",
            "min_dihedral_deg",
            "max_dihedral_deg",
        ] {
            assert!(json.get(key).is_some_and(|v| !v.is_null()), "{key}");
        }
        assert!(r.table().contains("tetrahedra             4608"));

        // The STL boundary encloses the same volume and is closed.
        let s = inspect(&stl, &InspectOptions::default()).unwrap();
        assert_eq!(s.surface_triangles, 1088);
        assert_eq!(s.problems_found, 0, "{:?}", s.problems);
        // STL stores f32 coordinates (relative rounding 6e-8).
        assert!((s.volume_m3 - expect).abs() < 1e-6 * expect);
    }

    #[test]
    fn problems_and_errors_name_things() {
        let dir = tempfile::tempdir().unwrap();
        // A cube with one tetrahedron reversed and one unused node, written
        // as TetGen files.
        let mut mesh = fissure_server::mesh::blocks::cube(1.0, 1);
        mesh.tets[3].swap(0, 1);
        mesh.nodes.push(nalgebra::Point3::new(5.0, 5.0, 5.0));
        let node = dir.path().join("m.node");
        let mut w = Vec::new();
        io::tetgen::write_node(&mut w, &mesh.nodes).unwrap();
        std::fs::write(&node, w).unwrap();
        let mut w = Vec::new();
        io::tetgen::write_ele(&mut w, &mesh.tets).unwrap();
        std::fs::write(dir.path().join("m.ele"), w).unwrap();
        let r = inspect(&node, &InspectOptions::default()).unwrap();
        assert_eq!(r.flipped_tets, 1);
        assert_eq!(r.problems, vec![Problem::UnusedNode { node: 8 }]);
        assert!(r.table().contains("node 8 is used by no element"));
        let s = convert(&node, &dir.path().join("out.vtu")).unwrap();
        assert!(
            s.contains("1 tetrahedra reoriented") && s.contains("1 unused nodes dropped"),
            "{s}"
        );

        let e = inspect(&dir.path().join("nope.msh"), &InspectOptions::default()).unwrap_err();
        assert!(e.to_string().contains("nope.msh"), "{e}");
        let e = convert(&node, &dir.path().join("x.txt")).unwrap_err();
        assert!(e.to_string().contains("x.txt"), "{e}");
        let e = convert(&dir.path().join("s.stl"), &dir.path().join("x.msh")).unwrap_err();
        assert!(e.to_string().contains("s.stl"), "{e}");
        assert!(
            preset_mesh(
                "brain",
                &PresetOptions {
                    size_m: 0.05,
                    cells: 2,
                    proven: false,
                }
            )
            .is_err()
        );
    }

    #[test]
    fn every_flag_has_help() {
        use clap::CommandFactory;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(subcommand)]
            cmd: MeshCommand,
        }
        let cmd = Cli::command();
        for sub in cmd.get_subcommands() {
            assert!(sub.get_about().is_some(), "{}", sub.get_name());
            for arg in sub.get_arguments() {
                if arg.get_id() == "help" {
                    continue;
                }
                assert!(
                    arg.get_help().is_some(),
                    "{} {}",
                    sub.get_name(),
                    arg.get_id()
                );
            }
        }
    }
}
