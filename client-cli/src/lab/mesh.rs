//! `fissure mesh ...`: generate, convert and inspect brain-model files.
//!
//! Each subcommand is a library function ([`generate`], [`convert`],
//! [`inspect`]) that returns plain data, so tests call it without a
//! subprocess; [`run`] prints.

use anyhow::{Context, bail};
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::io::{self, SurfaceFormat, VolumeFormat};
use fissure_engine::mesh::manifold::BoundaryRepair;
use fissure_engine::mesh::quality::{Histogram, QualitySummary, tets_quality};
use fissure_engine::mesh::units;
use fissure_engine::mesh::validate::{
    Findings, Problem, ValidateOptions, findings, surface_findings,
};
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
        /// A phantom preset's finest lattice spacing, mm, in place of its own
        /// (paper-48k: 4; coarse: 12), within 2 to 12; the elements grow
        /// about as the inverse cube of the spacing with --proven (paper-48k
        /// proven at 3.2 mm: about twice 204k).
        #[arg(long, value_name = "MM")]
        spacing_mm: Option<f64>,
        /// Split every tetrahedron into eight at its edge midpoints this
        /// many times (0 to 2): the same shape and surface at half the
        /// element size each time, 8 times the tetrahedra.
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=fissure_engine::mesh::refine::MAX_REFINEMENTS as i64))]
        refine: u32,
    },
    /// Mesh the inside of a closed triangle surface (.obj, .ply, .stl, or a
    /// .vtu of triangles) with tetrahedra (isosurface stuffing, uniform at the
    /// surface and graded inside, dihedral angles within the proven 8.9 to
    /// 158.8 degrees) and write it (format from the extension). An open,
    /// non-manifold or self-intersecting surface is refused with the
    /// offending element named, one over 1 m across as being in another unit
    /// (use --scale). Where two parts of the surface come closer than the
    /// resolution, the mesh's boundary is repaired to a closed manifold and
    /// the repair is reported.
    FromSurface {
        /// Closed surface file.
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
        /// Factor from the file's unit to metres, applied to the positions
        /// as read (0.001 for a file in millimetres).
        #[arg(long, value_name = "FACTOR", default_value_t = 1.0)]
        scale: f64,
    },
    /// Mesh a patient's brain from an MRI segmentation in NIfTI files (.nii
    /// or .nii.gz, NIfTI-1 or NIfTI-2) and write it (format from the
    /// extension; .vtu keeps the tissue labels as cell data "label"). The
    /// brain is the voxels whose summed value is above --threshold (a binary
    /// mask; probability maps such as grey and white matter), or, with
    /// --labels, the voxels of one label map carrying those labels. The mask
    /// becomes a signed distance field in scanner space (the image's sform,
    /// else its qform; oblique and flipped axes are fine) and is meshed by
    /// isosurface stuffing (dihedral angles within the proven 8.9 to 158.8
    /// degrees); a boundary pinched where sulci are narrower than the
    /// spacing is repaired to a closed manifold. Each tetrahedron carries a
    /// tissue label: the label map's value, or for several maps 1 + the index
    /// of the largest (grey 1, white 2 when given in that order), or 1.
    FromImage {
        /// Image files: one mask, one label map (with --labels), or several
        /// probability maps summed voxelwise (they must share dims and
        /// affine).
        #[arg(value_name = "IMAGE", required = true, num_args = 1..)]
        images: Vec<PathBuf>,
        /// Output volume mesh: .vtu, .msh, .vtk or .node/.ele.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// The brain labels of a label map, comma separated (e.g.
        /// 2,3,41,42); the tetrahedra keep them as their tissue labels.
        #[arg(long, value_name = "L,L,...", value_delimiter = ',', num_args = 1..)]
        labels: Option<Vec<u32>>,
        /// Brain where the voxelwise sum of the images is above this (0.5:
        /// a binary mask, or grey + white matter probabilities).
        #[arg(
            long,
            value_name = "T",
            default_value_t = 0.5,
            conflicts_with = "labels"
        )]
        threshold: f64,
        /// Tetrahedron size at the surface, in millimetres (2: twice the
        /// usual voxel; sulci narrower than it close or are repaired open).
        #[arg(long, value_name = "MM", default_value_t = 2.0)]
        spacing_mm: f64,
        /// Grading levels: tetrahedra grow up to 2^levels times the spacing
        /// away from the surface (0: uniform).
        #[arg(long, value_name = "N", default_value_t = 2)]
        levels: u32,
    },
    /// Convert a mesh file to another format (format from the extensions). A
    /// volume mesh written to .obj, .ply or .stl gives its boundary surface.
    Convert {
        /// Input file: .msh (Gmsh 2.2/4.1), .vtk, .vtu, .node/.ele (TetGen),
        /// or a surface .obj, .ply, .stl, or .vtu of triangles.
        #[arg(value_name = "IN")]
        input: PathBuf,
        /// Output file: .vtu, .msh (4.1), .vtk, .node/.ele, or a surface
        /// .obj, .ply (binary), .stl (binary), .vtu.
        #[arg(value_name = "OUT")]
        output: PathBuf,
        /// Factor applied to every position (0.001 turns a file in
        /// millimetres into metres).
        #[arg(long, value_name = "FACTOR", default_value_t = 1.0)]
        scale: f64,
    },
    /// Print counts, bounding box, volume, element quality and problems of a
    /// mesh file: a size implausible for metres, inverted or degenerate
    /// tetrahedra, an open or non-manifold boundary, duplicate or unused
    /// nodes; for a surface also an inside-out orientation and
    /// self-intersections.
    Inspect {
        /// Volume (.msh, .vtk, .vtu, .node/.ele) or surface (.obj, .ply, .stl,
        /// or a .vtu of triangles) file.
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
        /// Factor from the file's unit to metres, applied before the checks
        /// (0.001 for a file in millimetres).
        #[arg(long, value_name = "FACTOR", default_value_t = 1.0)]
        scale: f64,
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
            spacing_mm,
            refine,
        } => {
            let generated = generate(
                &preset,
                &out,
                &PresetOptions {
                    size_m: size,
                    cells,
                    proven,
                    spacing_m: spacing_mm.map(|h| h * 1e-3),
                    refine,
                },
            )?;
            if !generated.repair.is_empty() {
                println!("repaired: {}", generated.repair);
            }
            println!("wrote {}: {}", out.display(), generated.written);
        }
        MeshCommand::FromSurface {
            file,
            out,
            resolution,
            levels,
            scale,
        } => {
            let meshed = from_surface(&file, resolution, levels, scale)?;
            if meshed.inside_out {
                println!(
                    "note: {} is inside out (its triangles face inward); its inside was meshed all the same",
                    file.display()
                );
            }
            if !meshed.repair.is_empty() {
                println!("repaired: {}", meshed.repair);
            }
            let written = write_any(&meshed.mesh, &out)?;
            println!(
                "wrote {}: {written}; the boundary is a closed manifold",
                out.display()
            );
        }
        MeshCommand::FromImage {
            images,
            out,
            labels,
            threshold,
            spacing_mm,
            levels,
        } => {
            let opts = FromImageOptions {
                labels,
                threshold,
                spacing_mm,
                levels,
            };
            let report = from_image(&images, &opts)?;
            print!("{}", report.table());
            let written = write_any(&report.mesh, &out)?;
            println!(
                "wrote {}: {written}; the boundary is a closed manifold",
                out.display()
            );
        }
        MeshCommand::Convert {
            input,
            output,
            scale,
        } => {
            let s = convert(&input, &output, scale)?;
            println!("wrote {}: {s}", output.display());
        }
        MeshCommand::Inspect {
            file,
            json,
            duplicate_tolerance,
            bins,
            max_listed,
            scale,
        } => {
            let opts = InspectOptions {
                duplicate_tolerance,
                bins,
                max_listed,
                scale,
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

/// Reads a closed surface, scales it by `scale` (the file's unit to m) and
/// meshes its inside.
pub fn from_surface(
    file: &Path,
    resolution_m: f64,
    levels: u32,
    scale: f64,
) -> anyhow::Result<fissure_engine::mesh::from_surface::Meshed> {
    use fissure_engine::mesh::from_surface::{ClosedSurfaceError, SurfaceMeshing, mesh_surface};
    if !(resolution_m.is_finite() && resolution_m > 0.0) {
        bail!("--resolution must be a positive length in metres, got {resolution_m}");
    }
    units::check_scale(scale, "--scale").map_err(anyhow::Error::msg)?;
    let mut surface = fissure_engine::mesh::io::read_surface(file)?;
    units::scale_points(&mut surface.vertices, scale);
    let params = SurfaceMeshing {
        spacing: resolution_m,
        levels,
        rate: 0.5,
    };
    mesh_surface(&surface.vertices, &surface.triangles, &params).map_err(|e| match e {
        ClosedSurfaceError::Units(u) => {
            anyhow::anyhow!("{}: {u}: use --scale {}", file.display(), u.scale * scale)
        }
        e => anyhow::anyhow!("{}: {e}", file.display()),
    })
}

/// What `fissure mesh from-image` selects and how it meshes.
#[derive(Debug, Clone, PartialEq)]
pub struct FromImageOptions {
    /// Brain labels of one label map; `None`: threshold the summed images.
    pub labels: Option<Vec<u32>>,
    /// Threshold on the voxelwise sum (without labels).
    pub threshold: f64,
    /// Tetrahedron size at the surface, mm.
    pub spacing_mm: f64,
    /// Grading levels.
    pub levels: u32,
}

/// One tissue label of a mesh made from an image.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LabelVolume {
    /// The label.
    pub label: u32,
    /// Its tetrahedra.
    pub tets: usize,
    /// Their volume, mL.
    pub volume_ml: f64,
}

/// What `fissure mesh from-image` made, and the figures it reports.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ImageReport {
    /// The mesh, m, with a tissue label per tetrahedron.
    #[serde(skip)]
    pub mesh: TetMesh,
    /// The image files.
    pub images: Vec<String>,
    /// "NIfTI-1" or "NIfTI-2" (of the first image).
    pub format: &'static str,
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Voxel sizes (the affine's column norms), mm.
    pub voxel_size_mm: [f64; 3],
    /// "sform" or "qform".
    pub affine_source: String,
    /// How brain voxels were selected, in words.
    pub selection: String,
    /// The largest voxel value of the images.
    pub value_max: f64,
    /// A warning about the selection (a threshold on maps whose values are
    /// not probabilities in 0..1), if any.
    pub note: Option<String>,
    /// Brain voxels.
    pub brain_voxels: usize,
    /// Their volume, mL.
    pub brain_voxel_volume_ml: f64,
    /// Volume of the mesh, mL.
    pub volume_ml: f64,
    /// Volume per tissue label.
    pub labels: Vec<LabelVolume>,
    /// Nodes of the mesh.
    pub nodes: usize,
    /// Tetrahedra of the mesh.
    pub tets: usize,
    /// Triangles of its boundary.
    pub surface_triangles: usize,
    /// Smallest and largest dihedral angle, degrees.
    pub dihedral_deg: [f64; 2],
    /// The repair of the boundary.
    pub repair: BoundaryRepair,
    /// Pieces apart from the largest (islands of brain voxels), dropped.
    pub dropped_pieces: usize,
    /// Their tetrahedra.
    pub dropped_tets: usize,
}

impl ImageReport {
    /// The report as printed by `fissure mesh from-image`.
    pub fn table(&self) -> String {
        let v = self.voxel_size_mm;
        let mut s = format!(
            "images: {} ({}, affine from the {})\n",
            self.images.join(", "),
            self.format,
            self.affine_source
        );
        s += &format!(
            "grid: {} x {} x {} voxels of {:.3} x {:.3} x {:.3} mm\n",
            self.dims[0], self.dims[1], self.dims[2], v[0], v[1], v[2]
        );
        s += &format!(
            "brain: {} voxels ({:.1} mL), {}\n",
            self.brain_voxels, self.brain_voxel_volume_ml, self.selection
        );
        if let Some(note) = &self.note {
            s += &format!("note: {note}\n");
        }
        s += &format!(
            "mesh: {} nodes, {} tetrahedra, {} surface triangles, {:.1} mL\n",
            self.nodes, self.tets, self.surface_triangles, self.volume_ml
        );
        for l in &self.labels {
            s += &format!(
                "  label {}: {:.1} mL, {} tetrahedra\n",
                l.label, l.volume_ml, l.tets
            );
        }
        s += &format!(
            "dihedral angles: {:.1} to {:.1} degrees\n",
            self.dihedral_deg[0], self.dihedral_deg[1]
        );
        s += &format!("repair: {}\n", self.repair);
        if self.dropped_pieces > 0 {
            s += &format!(
                "dropped: {} pieces apart from the brain ({} tetrahedra; islands of brain voxels nothing would hold)\n",
                self.dropped_pieces, self.dropped_tets
            );
        }
        s
    }
}

/// Reads the images and meshes the brain they select (see
/// [`fissure_engine::mesh::image`]); returns the mesh and the report.
pub fn from_image(images: &[PathBuf], opts: &FromImageOptions) -> anyhow::Result<ImageReport> {
    use fissure_engine::mesh::image::{
        self, NiftiVersion, Selection, SurfaceMeshing, mesh_image, read_nifti,
    };
    if images.is_empty() {
        bail!("give at least one image");
    }
    let h = opts.spacing_mm;
    if !(h.is_finite() && h > 0.0) {
        bail!("--spacing-mm must be a positive length in millimetres, got {h}");
    }
    let read = images
        .iter()
        .map(|p| read_nifti(p))
        .collect::<Result<Vec<_>, _>>()?;
    let selection = match &opts.labels {
        Some(labels) => Selection::Labels {
            labels: labels.clone(),
        },
        None => Selection::Threshold {
            threshold: opts.threshold,
        },
    };
    let params = SurfaceMeshing {
        spacing: h * 1e-3,
        levels: opts.levels,
        rate: 0.5,
    };
    let meshed = mesh_image(&read, &selection, &params)?;
    let mesh = meshed.mesh;
    let first = &read[0];
    let sp = first.spacing_m();
    let ml = 1e6;
    let mut counts = std::collections::BTreeMap::<u32, usize>::new();
    for t in 0..mesh.tets.len() {
        *counts.entry(mesh.label(t)).or_default() += 1;
    }
    let labels = image::label_volumes(&mesh)
        .into_iter()
        .map(|(label, v)| LabelVolume {
            label,
            tets: counts.get(&label).copied().unwrap_or(0),
            volume_ml: v * ml,
        })
        .collect();
    let (lo, hi) = fissure_engine::mesh::stuffing::dihedral_range(&mesh);
    let value_max = read
        .iter()
        .flat_map(|im| im.values.iter().copied())
        .filter(|x| !x.is_nan())
        .fold(f64::NEG_INFINITY, f64::max);
    let note = match selection {
        Selection::Threshold { threshold } if value_max > 1.0 && threshold < 1.0 => Some(format!(
            "the images' values reach {value_max} (not probabilities in 0..1: uint8 maps store \
             255 for certainty), so --threshold {threshold} selects every voxel with a value; \
             for half of that scale use --threshold {}",
            value_max / 2.0
        )),
        _ => None,
    };
    Ok(ImageReport {
        images: images.iter().map(|p| p.display().to_string()).collect(),
        format: match first.version {
            NiftiVersion::One => "NIfTI-1",
            NiftiVersion::Two => "NIfTI-2",
        },
        dims: first.dims,
        voxel_size_mm: [sp[0] * 1e3, sp[1] * 1e3, sp[2] * 1e3],
        affine_source: first.affine_source.to_string(),
        selection: match &selection {
            Selection::Threshold { threshold } if read.len() > 1 => {
                format!("the sum of {} maps above {threshold}", read.len())
            }
            Selection::Threshold { threshold } => format!("values above {threshold}"),
            Selection::Labels { labels } => format!("labels {labels:?}"),
        },
        value_max,
        note,
        brain_voxels: meshed.brain_voxels,
        brain_voxel_volume_ml: meshed.brain_voxel_volume_m3 * ml,
        volume_ml: (0..mesh.tets.len())
            .map(|t| mesh.signed_volume(t))
            .sum::<f64>()
            * ml,
        labels,
        nodes: mesh.nodes.len(),
        tets: mesh.tets.len(),
        surface_triangles: mesh.boundary().triangles.len(),
        dihedral_deg: [lo, hi],
        repair: meshed.repair,
        dropped_pieces: meshed.dropped_pieces,
        dropped_tets: meshed.dropped_tets,
        mesh,
    })
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
    /// A phantom preset's finest lattice spacing, m, in place of its own.
    pub spacing_m: Option<f64>,
    /// Uniform refinements of the meshed preset ([`fissure_engine::mesh::refine`]).
    pub refine: u32,
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
    preset_mesh_repaired(name, cube).map(|(mesh, _)| mesh)
}

/// The mesh of a named preset, with the repair of the mesher's output that
/// made its boundary a closed manifold (empty for the blocks).
pub fn preset_mesh_repaired(
    name: &str,
    cube: &PresetOptions,
) -> anyhow::Result<(TetMesh, BoundaryRepair)> {
    use fissure_engine::mesh::blocks;
    // The single list of presets (keep PRESETS in step).
    let block = |mesh| (mesh, BoundaryRepair::default());
    let (mesh, repair) = match name {
        "coarse" | "paper-34k" | "paper-48k" => {
            if let Some(h) = cube.spacing_m {
                use fissure_engine::scene::{
                    MAX_PHANTOM_SPACING_M, MIN_PHANTOM_SPACING_M, phantom_spacing_allowed,
                };
                if !phantom_spacing_allowed(h) {
                    bail!(
                        "--spacing-mm must be within {} to {} mm, got {}",
                        MIN_PHANTOM_SPACING_M * 1e3,
                        MAX_PHANTOM_SPACING_M * 1e3,
                        h * 1e3
                    );
                }
            }
            let p =
                fissure_engine::mesh::phantom::preset_meshed(name, cube.proven, cube.spacing_m)?;
            (p.mesh, p.repair)
        }
        _ if cube.spacing_m.is_some() && PRESETS.contains(&name) => {
            bail!("--spacing-mm applies to the phantom presets, not '{name}'")
        }
        "cube" => {
            if !(cube.size_m > 0.0 && cube.size_m.is_finite()) || cube.cells == 0 {
                bail!(
                    "cube: size must be positive (got {} m) and cells at least 1",
                    cube.size_m
                );
            }
            block(blocks::cube(cube.size_m, cube.cells))
        }
        "v-valley" => block(blocks::v_valley()),
        "u-valley" => block(blocks::u_valley()),
        other => bail!("unknown preset '{other}' (known: {})", PRESETS.join(", ")),
    };
    if cube.refine > fissure_engine::mesh::refine::MAX_REFINEMENTS {
        bail!(
            "--refine must be at most {}, got {}",
            fissure_engine::mesh::refine::MAX_REFINEMENTS,
            cube.refine
        );
    }
    let mesh = fissure_engine::mesh::refine::uniform_times(mesh, cube.refine)
        .context("refining the mesh")?;
    Ok((mesh, repair))
}

/// A preset as [`generate`] wrote it.
#[derive(Debug, Clone)]
pub struct Generated {
    /// The volume mesh.
    pub mesh: TetMesh,
    /// The repair of the mesher's output that made its boundary a closed
    /// manifold (empty when none was needed).
    pub repair: BoundaryRepair,
    /// What the file holds: nodes and tetrahedra for a volume format, the
    /// boundary's vertices and triangles for a surface format.
    pub written: String,
}

/// Generates a preset and writes it to `out` (a volume format, or a surface
/// format for its boundary).
pub fn generate(preset: &str, out: &Path, cube: &PresetOptions) -> anyhow::Result<Generated> {
    let (mesh, repair) = preset_mesh_repaired(preset, cube)?;
    let written = write_any(&mesh, out)?;
    Ok(Generated {
        mesh,
        repair,
        written,
    })
}

/// Writes `mesh` to `out`: the volume, or its boundary surface for a surface
/// format. Returns what was written (the counts of what the file holds, not
/// of the volume it came from).
fn write_any(mesh: &TetMesh, out: &Path) -> anyhow::Result<String> {
    if VolumeFormat::from_path(out).is_some() {
        io::write_volume(out, mesh)?;
        Ok(format!(
            "{} nodes, {} tetrahedra",
            mesh.nodes.len(),
            mesh.tets.len()
        ))
    } else {
        let b = mesh.boundary();
        let mut v = Vec::new();
        b.gather(&mesh.nodes, &mut v);
        io::write_surface(out, &v, &b.triangles)?;
        Ok(format!(
            "the boundary surface, {} vertices, {} triangles",
            v.len(),
            b.triangles.len()
        ))
    }
}

/// A mesh file as read: a volume (every node of the file, tetrahedra as in
/// the file) or a surface (a surface format, or a `.vtu` of triangles only,
/// such as `fissure watch` writes).
#[derive(Debug, Clone)]
pub enum Loaded {
    /// Tetrahedra.
    Volume(io::RawVolume),
    /// Triangles.
    Surface(io::SurfaceMesh),
}

/// Reads a mesh file, volume or surface, by its extension and content.
pub fn load(path: &Path) -> anyhow::Result<Loaded> {
    if SurfaceFormat::from_path(path).is_some() {
        return Ok(Loaded::Surface(io::read_surface(path)?));
    }
    let Some(format) = VolumeFormat::from_path(path) else {
        return Err(io::IoError::UnknownFormat {
            path: path.to_path_buf(),
            expected: "expected .msh, .vtk, .vtu, .node, .ele, .obj, .ply or .stl",
        }
        .into());
    };
    let raw = io::read_volume_raw(path)?;
    if raw.tets.is_empty() && format == VolumeFormat::Vtu {
        // No tetrahedra: a surface .vtu, or an error naming what is missing.
        return Ok(Loaded::Surface(io::read_surface(path)?));
    }
    Ok(Loaded::Volume(raw))
}

/// Converts `input` to `output`, positions multiplied by `scale`; returns a
/// one-line summary of what was read and what was written.
pub fn convert(input: &Path, output: &Path, scale: f64) -> anyhow::Result<String> {
    units::check_scale(scale, "--scale").map_err(anyhow::Error::msg)?;
    let out_volume = VolumeFormat::from_path(output).is_some();
    let out_surface = SurfaceFormat::from_path(output).is_some() || out_volume;
    if !out_surface {
        bail!(
            "{}: unknown output format (expected .vtu, .msh, .vtk, .node, .ele, .obj, .ply or .stl)",
            output.display()
        );
    }
    match load(input)? {
        Loaded::Volume(raw) => {
            if raw.tets.is_empty() {
                return Err(io::IoError::NoTetrahedra {
                    path: input.to_path_buf(),
                    ignored: raw.ignored_cells,
                }
                .into());
            }
            let mut r = io::finish_volume(raw).map_err(|source| io::IoError::Mesh {
                path: input.to_path_buf(),
                source,
            })?;
            units::scale_points(&mut r.mesh.nodes, scale);
            let written = write_any(&r.mesh, output)?;
            let mut s = format!(
                "read {} nodes, {} tetrahedra",
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
            Ok(format!("{s}; wrote {written}"))
        }
        Loaded::Surface(mut surface) => {
            if out_volume
                && !output
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("vtu"))
            {
                bail!(
                    "{}: a surface cannot be converted to a volume format; mesh its inside first \
                     (`fissure mesh from-surface`)",
                    input.display()
                );
            }
            units::scale_points(&mut surface.vertices, scale);
            io::write_surface(output, &surface.vertices, &surface.triangles)?;
            Ok(format!(
                "wrote the surface, {} vertices, {} triangles",
                surface.vertices.len(),
                surface.triangles.len()
            ))
        }
    }
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
    /// Factor applied to the positions before the checks (the file's unit
    /// to m).
    pub scale: f64,
}

impl Default for InspectOptions {
    fn default() -> Self {
        Self {
            duplicate_tolerance: 1e-9,
            bins: 10,
            max_listed: 20,
            scale: 1.0,
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
    /// Number of problems found, all of them.
    pub problems_found: usize,
    /// The first problems.
    pub problems: Vec<Problem>,
}

/// Reads a mesh file and reports on it. The tetrahedra are checked as
/// [`io::read_volume`] would load them (negatively oriented ones reoriented)
/// but with every node of the file, so unused nodes show up as problems. A
/// `.vtu` holding triangles only is inspected as a surface. Positions are
/// multiplied by `opts.scale` first.
pub fn inspect(path: &Path, opts: &InspectOptions) -> anyhow::Result<Report> {
    units::check_scale(opts.scale, "--scale").map_err(anyhow::Error::msg)?;
    let vopts = ValidateOptions {
        duplicate_tolerance: opts.duplicate_tolerance,
        max_problems: opts.max_listed,
        ..Default::default()
    };
    let file = path.display().to_string();
    let listed = |f: Findings| (f.total, f.problems);
    match load(path).with_context(|| format!("inspecting {}", path.display()))? {
        Loaded::Volume(mut raw) => {
            units::scale_points(&mut raw.nodes, opts.scale);
            let mut tets = raw.tets.clone();
            let mut flipped = 0;
            for t in &mut tets {
                let [a, b, c, d] = t.map(|i| raw.nodes[i as usize]);
                if (b - a).cross(&(c - a)).dot(&(d - a)) < 0.0 {
                    t.swap(2, 3);
                    flipped += 1;
                }
            }
            let (problems_found, problems) = listed(findings(&raw.nodes, &tets, &vopts));
            let q = tets_quality(&raw.nodes, &tets);
            let s = QualitySummary::of(&q);
            let mesh = TetMesh {
                nodes: raw.nodes,
                tets,
                labels: Vec::new(),
            };
            let surface_triangles = mesh.boundary().triangles.len();
            let (lo, hi) = mesh.bounds();
            let bins = opts.bins.max(1);
            Ok(Report {
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
                problems_found,
                problems,
            })
        }
        Loaded::Surface(mut s) => {
            units::scale_points(&mut s.vertices, opts.scale);
            let (problems_found, problems) =
                listed(surface_findings(&s.vertices, &s.triangles, &vopts));
            let mesh = TetMesh {
                nodes: s.vertices.clone(),
                tets: Vec::new(),
                labels: Vec::new(),
            };
            let (lo, hi) = mesh.bounds();
            let volume = fissure_engine::mesh::enclosed_volume(&s.vertices, &s.triangles);
            Ok(Report {
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
                problems_found,
                problems,
            })
        }
    }
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
        use fissure_engine::mesh::{io, winding::icosphere};
        let dir = tempfile::tempdir().unwrap();
        let (v, t) = icosphere(nalgebra::Point3::origin(), 0.02, 3);
        let obj = dir.path().join("sphere.obj");
        io::write_surface(&obj, &v, &t).unwrap();
        let mesh = from_surface(&obj, 0.003, 1, 1.0).unwrap().mesh;
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
        let err = from_surface(&open, 0.003, 1, 1.0).unwrap_err().to_string();
        assert!(err.contains("open.obj") && err.contains("edge"), "{err}");
        assert!(from_surface(&obj, -1.0, 0, 1.0).is_err());
    }

    #[test]
    fn a_proven_phantom_has_its_angles_within_the_proven_bounds() {
        use fissure_engine::mesh::stuffing::{PROVEN_MAX_DIHEDRAL_DEG, PROVEN_MIN_DIHEDRAL_DEG};
        let dir = tempfile::tempdir().unwrap();
        let vtu = dir.path().join("p.vtu");
        let opts = |proven| PresetOptions {
            size_m: 0.05,
            cells: 8,
            proven,
            spacing_m: None,
            refine: 0,
        };
        let proven = generate("coarse", &vtu, &opts(true)).unwrap().mesh;
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
        let Generated {
            mesh,
            repair,
            written,
        } = generate(
            "v-valley",
            &vtu,
            &PresetOptions {
                size_m: 0.05,
                cells: 8,
                proven: false,
                spacing_m: None,
                refine: 0,
            },
        )
        .unwrap();
        assert_eq!(mesh.tets.len(), 4608);
        assert!(repair.is_empty());
        assert_eq!(
            written,
            format!("{} nodes, 4608 tetrahedra", mesh.nodes.len())
        );

        let msh = dir.path().join("v.msh");
        let summary = convert(&vtu, &msh, 1.0).unwrap();
        assert_eq!(
            summary,
            format!(
                "read {n} nodes, 4608 tetrahedra; wrote {n} nodes, 4608 tetrahedra",
                n = mesh.nodes.len()
            )
        );
        let stl = dir.path().join("v.stl");
        // To a surface format: the triangles written are reported.
        let summary = convert(&msh, &stl, 1.0).unwrap();
        assert!(
            summary.ends_with("wrote the boundary surface, 546 vertices, 1088 triangles"),
            "{summary}"
        );

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
        let mut mesh = fissure_engine::mesh::blocks::cube(0.01, 1);
        mesh.tets[3].swap(0, 1);
        mesh.nodes.push(nalgebra::Point3::new(0.05, 0.05, 0.05));
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
        let s = convert(&node, &dir.path().join("out.vtu"), 1.0).unwrap();
        assert!(
            s.contains("1 tetrahedra reoriented") && s.contains("1 unused nodes dropped"),
            "{s}"
        );

        let e = inspect(&dir.path().join("nope.msh"), &InspectOptions::default()).unwrap_err();
        assert!(e.to_string().contains("nope.msh"), "{e}");
        let e = convert(&node, &dir.path().join("x.txt"), 1.0).unwrap_err();
        assert!(e.to_string().contains("x.txt"), "{e}");
        let e = convert(&dir.path().join("s.stl"), &dir.path().join("x.msh"), 1.0).unwrap_err();
        assert!(e.to_string().contains("s.stl"), "{e}");
        assert!(
            preset_mesh(
                "brain",
                &PresetOptions {
                    size_m: 0.05,
                    cells: 2,
                    proven: false,
                    spacing_m: None,
                    refine: 0,
                }
            )
            .is_err()
        );
        // A spacing outside its range, or on a block, names the flag.
        for (name, h) in [("coarse", 0.0005), ("coarse", f64::NAN), ("cube", 0.004)] {
            let e = preset_mesh(
                name,
                &PresetOptions {
                    size_m: 0.05,
                    cells: 2,
                    proven: false,
                    spacing_m: Some(h),
                    refine: 0,
                },
            )
            .unwrap_err();
            assert!(e.to_string().contains("--spacing-mm"), "{name} {h}: {e}");
        }
    }

    /// A .vtu of triangles only (what `fissure watch` writes) is a surface:
    /// inspected as one (no "0 tets" volume, no problems, its enclosed
    /// volume), converted to STL, refused as a volume format.
    #[test]
    fn surface_vtus_are_inspected_and_converted_as_surfaces() {
        use fissure_engine::mesh::winding::icosphere;
        let dir = tempfile::tempdir().unwrap();
        let (v, t) = icosphere(nalgebra::Point3::origin(), 0.02, 2);
        let vtu = dir.path().join("surface-000001.vtu");
        let mut bytes = Vec::new();
        io::vtu::write_vtu_surface(&mut bytes, &v, &t, &[], &[]).unwrap();
        std::fs::write(&vtu, bytes).unwrap();
        let r = inspect(&vtu, &InspectOptions::default()).unwrap();
        assert_eq!(
            (r.kind, r.tets, r.surface_triangles, r.problems_found),
            ("surface", 0, t.len(), 0),
            "{:?}",
            r.problems
        );
        let sphere = 4.0 / 3.0 * std::f64::consts::PI * 0.02f64.powi(3);
        assert!(r.volume_m3 > 0.9 * sphere && r.volume_m3 < sphere);
        let stl = dir.path().join("s.stl");
        assert_eq!(
            convert(&vtu, &stl, 1.0).unwrap(),
            format!(
                "wrote the surface, {} vertices, {} triangles",
                v.len(),
                t.len()
            )
        );
        let e = convert(&vtu, &dir.path().join("s.msh"), 1.0).unwrap_err();
        assert!(e.to_string().contains("mesh its inside first"), "{e}");
    }

    /// Every problem is counted (12,000 unused vertices; 20 listed, the
    /// table says how many more); a closed surface facing inward is inside
    /// out; two crossing spheres intersect (inspect checks as from-surface
    /// does).
    #[test]
    fn inspect_counts_every_problem_and_checks_orientation_and_intersections() {
        use fissure_engine::mesh::winding::{icosphere, join_surfaces};
        let dir = tempfile::tempdir().unwrap();
        let (mut v, mut t) = icosphere(nalgebra::Point3::origin(), 0.02, 2);
        let n = v.len();
        v.extend((0..12_000).map(|k| nalgebra::Point3::new(0.03 + k as f64 * 1e-6, 0.0, 0.0)));
        let obj = dir.path().join("unused.obj");
        io::write_surface(&obj, &v, &t).unwrap();
        let r = inspect(&obj, &InspectOptions::default()).unwrap();
        assert_eq!((r.problems_found, r.problems.len()), (12_000, 20));
        assert!(r.table().contains("... 11980 more"), "{}", r.table());
        v.truncate(n);
        for tri in &mut t {
            tri.swap(1, 2);
        }
        let flipped = dir.path().join("flipped.stl");
        io::write_surface(&flipped, &v, &t).unwrap();
        let r = inspect(&flipped, &InspectOptions::default()).unwrap();
        assert!(r.volume_m3 < 0.0);
        assert!(
            matches!(r.problems.as_slice(), [Problem::InsideOut { .. }]),
            "{:?}",
            r.problems
        );
        assert!(r.table().contains("the surface is inside out"));
        let (v1, t1) = icosphere(nalgebra::Point3::origin(), 0.02, 1);
        let (v, t) = join_surfaces(
            (v1, t1),
            icosphere(nalgebra::Point3::new(0.01, 0.0, 0.0), 0.02, 1),
        );
        let crossing = dir.path().join("crossing.ply");
        io::write_surface(&crossing, &v, &t).unwrap();
        let r = inspect(&crossing, &InspectOptions::default()).unwrap();
        assert!(r.problems_found > 0);
        assert!(
            r.problems
                .iter()
                .all(|p| matches!(p, Problem::SelfIntersection { .. })),
            "{:?}",
            r.problems
        );
    }

    /// A 20 mm sphere written in millimetres: from-surface refuses it with
    /// "this looks like millimetres: use --scale 0.001" before meshing, and
    /// meshes it with --scale 0.001; a volume in millimetres is a problem for
    /// inspect (with the scale), none with --scale 0.001, and convert
    /// --scale 0.001 writes it in metres.
    #[test]
    fn files_in_millimetres_are_named_and_scale_converts_them() {
        use fissure_engine::mesh::winding::icosphere;
        let dir = tempfile::tempdir().unwrap();
        let (v, t) = icosphere(nalgebra::Point3::origin(), 20.0, 3);
        let obj = dir.path().join("sphere-mm.obj");
        io::write_surface(&obj, &v, &t).unwrap();
        let e = from_surface(&obj, 0.003, 1, 1.0).unwrap_err().to_string();
        assert!(
            e.contains("sphere-mm.obj")
                && e.ends_with("this looks like millimetres: use --scale 0.001"),
            "{e}"
        );
        let meshed = from_surface(&obj, 0.003, 1, 0.001).unwrap();
        assert!(meshed.repair.is_empty() && !meshed.inside_out);
        let volume: f64 = (0..meshed.mesh.tets.len())
            .map(|e| meshed.mesh.signed_volume(e))
            .sum();
        let sphere = 4.0 / 3.0 * std::f64::consts::PI * 0.02f64.powi(3);
        assert!((volume / sphere - 1.0).abs() < 0.05, "{volume}");

        let mut mm = meshed.mesh.clone();
        units::scale_points(&mut mm.nodes, 1000.0);
        let vtu = dir.path().join("volume-mm.vtu");
        io::write_volume(&vtu, &mm).unwrap();
        let r = inspect(&vtu, &InspectOptions::default()).unwrap();
        match r.problems.as_slice() {
            [Problem::ImplausibleSize(u)] => assert_eq!((u.unit, u.scale), ("millimetres", 1e-3)),
            other => panic!("{other:?}"),
        }
        let opts = InspectOptions {
            scale: 1e-3,
            ..Default::default()
        };
        assert_eq!(inspect(&vtu, &opts).unwrap().problems_found, 0);
        let metres = dir.path().join("volume-m.msh");
        convert(&vtu, &metres, 1e-3).unwrap();
        let r = inspect(&metres, &InspectOptions::default()).unwrap();
        assert_eq!(r.problems_found, 0, "{:?}", r.problems);
        assert!((r.bounding_box_m[1][0] - 0.02).abs() < 1e-3, "{r:?}");
    }

    /// paper-34k: the graded mesher pinches its boundary at four edges (a
    /// fissure wall closer to another surface than the lattice resolves);
    /// generate repairs and reports it, and the file has no problem.
    #[test]
    fn a_pinched_phantom_is_repaired_and_reported() {
        let dir = tempfile::tempdir().unwrap();
        let vtu = dir.path().join("p34.vtu");
        let opts = PresetOptions {
            size_m: 0.05,
            cells: 8,
            proven: false,
            spacing_m: None,
            refine: 0,
        };
        let Generated { mesh, repair, .. } = generate("paper-34k", &vtu, &opts).unwrap();
        assert_eq!(
            (repair.pinched_edges, repair.pinched_nodes),
            (4, 0),
            "{repair}"
        );
        assert!(
            repair.removed_volume_m3 < 1e-3 * repair.volume_m3,
            "{repair}"
        );
        let r = inspect(&vtu, &InspectOptions::default()).unwrap();
        assert_eq!(r.problems_found, 0, "{:?}", r.problems);
        assert_eq!(r.tets, mesh.tets.len());
    }

    /// `--refine` splits every tetrahedron into eight and writes a valid
    /// mesh of the same block; more refinements than allowed are refused.
    #[test]
    fn a_refined_preset_has_eight_times_the_tetrahedra_and_no_problem() {
        let dir = tempfile::tempdir().unwrap();
        let opts = |refine| PresetOptions {
            size_m: 0.05,
            cells: 2,
            proven: false,
            spacing_m: None,
            refine,
        };
        let vtu = dir.path().join("cube.vtu");
        let plain = generate("cube", &vtu, &opts(0)).unwrap();
        let refined = generate("cube", &vtu, &opts(1)).unwrap();
        assert_eq!(refined.mesh.tets.len(), 8 * plain.mesh.tets.len());
        let r = inspect(&vtu, &InspectOptions::default()).unwrap();
        assert_eq!(r.problems_found, 0, "{:?}", r.problems);
        assert_eq!(r.tets, refined.mesh.tets.len());
        let e = generate("cube", &vtu, &opts(3)).unwrap_err().to_string();
        assert!(e.contains("--refine"), "{e}");
    }

    /// A volume written to a surface format (generate, convert) reports the
    /// vertices and triangles of the surface written, the counts the file
    /// holds when read back, not the tetrahedra it came from.
    #[test]
    fn a_volume_written_as_stl_reports_the_triangles_written() {
        let dir = tempfile::tempdir().unwrap();
        let opts = PresetOptions {
            size_m: 0.05,
            cells: 4,
            proven: false,
            spacing_m: None,
            refine: 0,
        };
        let stl = dir.path().join("cube.stl");
        let g = generate("cube", &stl, &opts).unwrap();
        // 6 faces of 4 x 4 cells, 2 triangles each; 5 x 5 nodes a face,
        // shared along edges and corners.
        let (vertices, triangles) = (6 * 25 - 12 * 5 + 8, 6 * 16 * 2);
        assert_eq!(
            g.written,
            format!("the boundary surface, {vertices} vertices, {triangles} triangles")
        );
        assert_eq!(g.mesh.tets.len(), 4 * 4 * 4 * 6);
        let back = inspect(&stl, &InspectOptions::default()).unwrap();
        assert_eq!((back.kind, back.surface_triangles), ("surface", triangles));
        let vtu = dir.path().join("cube.vtu");
        generate("cube", &vtu, &opts).unwrap();
        let ply = dir.path().join("cube.ply");
        let s = convert(&vtu, &ply, 1.0).unwrap();
        assert!(
            s.ends_with(&format!(
                "wrote the boundary surface, {vertices} vertices, {triangles} triangles"
            )),
            "{s}"
        );
    }

    /// A NIfTI-1 file of u8 voxels (i fastest) with sform `rows` (mm).
    fn nifti1_u8(dims: [usize; 3], values: &[u8], rows: [[f32; 4]; 3]) -> Vec<u8> {
        let mut h = vec![0u8; 352];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        for (k, d) in [3, dims[0], dims[1], dims[2], 1, 1, 1, 1]
            .iter()
            .enumerate()
        {
            h[40 + 2 * k..42 + 2 * k].copy_from_slice(&(*d as i16).to_le_bytes());
        }
        h[70..72].copy_from_slice(&2i16.to_le_bytes()); // uint8
        h[72..74].copy_from_slice(&8i16.to_le_bytes());
        for k in 0..8 {
            h[76 + 4 * k..80 + 4 * k].copy_from_slice(&1f32.to_le_bytes());
        }
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        h[123] = 2; // mm
        h[254..256].copy_from_slice(&1i16.to_le_bytes()); // sform_code
        for (r, row) in rows.iter().enumerate() {
            for (c, x) in row.iter().enumerate() {
                let o = 280 + 16 * r + 4 * c;
                h[o..o + 4].copy_from_slice(&x.to_le_bytes());
            }
        }
        h[344..348].copy_from_slice(b"n+1\0");
        h.extend_from_slice(values);
        h
    }

    /// A label map of a ball (r = 10 mm, labels 3 and 5 on either side of
    /// x = 0, decoy label 9 elsewhere) meshes through
    /// `from_image` to the ball's volume (within 5%), each half within 10% of
    /// its share, the labels kept through a .vtu; thresholded instead, it is
    /// one tissue (label 1) with the decoy included; --labels with two
    /// images is refused.
    #[test]
    fn from_image_meshes_a_label_map_and_keeps_its_labels() {
        let dims = [26usize, 26, 26];
        let mut values = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let p = [i as f64 - 12.5, j as f64 - 12.5, k as f64 - 12.5];
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    values.push(match (r < 10.0, p[0] < 0.0) {
                        (true, true) => 3u8,
                        (true, false) => 5,
                        _ if i == 0 && j == 0 => 9,
                        _ => 0,
                    });
                }
            }
        }
        let rows = [
            [1.0, 0.0, 0.0, -12.5],
            [0.0, 1.0, 0.0, -12.5],
            [0.0, 0.0, 1.0, -12.5],
        ];
        let dir = tempfile::tempdir().unwrap();
        let nii = dir.path().join("labels.nii");
        std::fs::write(&nii, nifti1_u8(dims, &values, rows)).unwrap();
        let opts = FromImageOptions {
            labels: Some(vec![3, 5]),
            threshold: 0.5,
            spacing_mm: 2.0,
            levels: 1,
        };
        let report = from_image(std::slice::from_ref(&nii), &opts).unwrap();
        let ball = 4.0 / 3.0 * std::f64::consts::PI; // mL, r = 1 cm
        assert!(
            (report.volume_ml / ball - 1.0).abs() < 0.05,
            "{}",
            report.table()
        );
        let got: Vec<u32> = report.labels.iter().map(|l| l.label).collect();
        assert_eq!(got, vec![3, 5]);
        for l in &report.labels {
            assert!(
                (l.volume_ml / (ball / 2.0) - 1.0).abs() < 0.1,
                "{}",
                report.table()
            );
        }
        assert_eq!(
            report.brain_voxels,
            values.iter().filter(|&&v| v == 3 || v == 5).count()
        );
        assert_eq!(
            (report.affine_source.as_str(), report.format),
            ("sform", "NIfTI-1")
        );
        assert!(report.table().contains("label 5:"), "{}", report.table());
        let vtu = dir.path().join("brain.vtu");
        write_any(&report.mesh, &vtu).unwrap();
        let back = io::read_volume(&vtu).unwrap();
        assert_eq!(back.labels, report.mesh.labels);

        let one = FromImageOptions {
            labels: None,
            ..opts.clone()
        };
        let report = from_image(std::slice::from_ref(&nii), &one).unwrap();
        assert_eq!(report.labels.len(), 1);
        assert_eq!(report.labels[0].label, 1);
        assert_eq!(
            report.brain_voxels,
            values.iter().filter(|&&v| v > 0).count()
        );

        let e = from_image(&[nii.clone(), nii.clone()], &opts).unwrap_err();
        assert!(e.to_string().contains("one label map"), "{e}");
        let bad = FromImageOptions {
            spacing_mm: 0.0,
            ..opts
        };
        assert!(
            from_image(&[nii], &bad)
                .unwrap_err()
                .to_string()
                .contains("--spacing-mm")
        );
    }

    /// The subcommand's arguments parse as documented: several images,
    /// comma-separated labels, and --threshold refused beside --labels.
    #[test]
    fn from_image_arguments_parse() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(subcommand)]
            cmd: MeshCommand,
        }
        let cli = Cli::try_parse_from([
            "x",
            "from-image",
            "gm.nii.gz",
            "wm.nii.gz",
            "--out",
            "b.vtu",
        ])
        .unwrap();
        match cli.cmd {
            MeshCommand::FromImage {
                images,
                labels,
                threshold,
                spacing_mm,
                levels,
                ..
            } => {
                assert_eq!(images.len(), 2);
                assert_eq!((labels, threshold, spacing_mm, levels), (None, 0.5, 2.0, 2));
            }
            _ => panic!("not from-image"),
        }
        let cli = Cli::try_parse_from([
            "x",
            "from-image",
            "aseg.nii",
            "--labels",
            "2,3,41,42",
            "--out",
            "b.vtu",
        ])
        .unwrap();
        match cli.cmd {
            MeshCommand::FromImage { labels, .. } => {
                assert_eq!(labels, Some(vec![2, 3, 41, 42]))
            }
            _ => panic!("not from-image"),
        }
        assert!(
            Cli::try_parse_from([
                "x",
                "from-image",
                "a.nii",
                "--labels",
                "2",
                "--threshold",
                "0.3",
                "--out",
                "b.vtu",
            ])
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
