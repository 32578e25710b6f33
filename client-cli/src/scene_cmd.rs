//! `fissure scene from-image`: a running scene from a patient's image: the
//! brain meshed from the image (`fissure mesh from-image`), the fissure
//! found near a point the user gives ([`fissure_server::mesh::fissure`]),
//! and a scene folder a demo runs as it is.
//!
//! The folder holds `model.vtu` (the labelled mesh, scanner coordinates in
//! m), `scene.toml` (a material per tissue with its source, the fixed
//! region, the foundation opened about the fissure, two spatulas at home
//! outside the fissure's entry) and `open.csv` (both spatulas: insert, open
//! the fissure, hold, close, retract; the `instrument,t_s,...` trajectory
//! set of [`crate::trajectory`]). `fissure demo --scene DIR/scene.toml
//! --trajectory DIR/open.csv` runs it.

use anyhow::{Context, bail};
use fissure_server::collide::FissurePlacement;
use fissure_server::mesh::TetMesh;
use fissure_server::mesh::fissure::{FoundFissure, Probe};
use fissure_server::mesh::phantom::FissureLandmark;
use nalgebra::{Point3, UnitQuaternion};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Young's modulus of grey matter, Pa: 1.389 kPa, Budday et al., "Mechanical
/// properties of gray and white matter brain tissue by indentation", J.
/// Mech. Behav. Biomed. Mater. 46 (2015) 318-330 (bovine, ex vivo,
/// indentation; their mean).
pub const GREY_MATTER_PA: f64 = 1389.0;
/// Young's modulus of white matter, Pa: 1.895 kPa, the same study.
pub const WHITE_MATTER_PA: f64 = 1895.0;
/// Poisson's ratio of both: nearly incompressible tissue, the value of the
/// bundled scenes (0.45; the study assumes incompressibility, the linear
/// tetrahedron needs nu below 0.5).
pub const BRAIN_POISSON: f64 = 0.45;

/// The spatula of the generated scene: the bundled scenes' flat plate.
const PLATE_THICKNESS_M: f64 = 0.001;
const PLATE_WIDTH_M: f64 = 0.008;
const PLATE_LENGTH_M: f64 = 0.030;

/// Where the brain is held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixedChoice {
    /// The elements of this tissue label (the brain stem of a label map:
    /// 16 in FreeSurfer's and SynthSeg's lookup tables), by the box of their
    /// nodes.
    Label(u32),
    /// The nodes within `height_m` of the lowest point and within
    /// `half_width_m` of the mesh's mid-sagittal plane (`x` of the bounds'
    /// centre): the brain stem's place in a brain in RAS+ scanner axes.
    Bottom { height_m: f64, half_width_m: f64 },
}

/// A tissue of the generated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneTissue {
    /// Label in the mesh.
    pub label: u32,
    /// Name.
    pub name: String,
    /// Young's modulus, Pa.
    pub youngs_modulus_pa: f64,
    /// Where the value comes from (written beside it in the scene).
    pub source: String,
}

/// What the scene is made of.
#[derive(Debug, Clone)]
pub struct SceneRequest<'a> {
    /// Scene name.
    pub name: String,
    /// The labelled mesh (scanner coordinates, m).
    pub mesh: &'a TetMesh,
    /// The fissure the spatulas open.
    pub fissure: FoundFissure,
    /// Where the brain is held.
    pub fixed: FixedChoice,
    /// Materials per tissue (labels of the mesh).
    pub tissues: Vec<SceneTissue>,
    /// How far the tips go past the fissure's entry, m (capped at the depth
    /// found).
    pub insertion_m: f64,
    /// How far each plate pushes its wall beyond the gap, m.
    pub push_m: f64,
    /// The region of interest: tissue farther than this from the fissure's
    /// point is cropped away (its cut held), m; `None`: the whole brain.
    pub roi_m: Option<f64>,
}

/// The files written and what they hold.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFiles {
    /// `model.vtu`.
    pub model: PathBuf,
    /// `scene.toml`.
    pub scene: PathBuf,
    /// `open.csv`.
    pub trajectory: PathBuf,
    /// The fixed box, m.
    pub fixed_box_m: ([f64; 3], [f64; 3]),
    /// Nodes in the fixed box.
    pub fixed_nodes: usize,
    /// Depth the tips reach past the entry, m.
    pub insertion_m: f64,
    /// Offsets of the left and right plate across the fissure (along
    /// `d x n`), m.
    pub across_m: [f64; 2],
    /// Fraction of the plates' body samples in the tissue at full insertion
    /// (0: both lie in the gap; a curved or narrow fissure makes them graze
    /// its walls from the start).
    pub grazing: f64,
}

/// The box of the fixed region and the number of nodes in it.
fn fixed_box(mesh: &TetMesh, fixed: FixedChoice) -> anyhow::Result<([f64; 3], [f64; 3], usize)> {
    let (lo, hi) = match fixed {
        FixedChoice::Label(label) => {
            let mut lo = Point3::from([f64::INFINITY; 3]);
            let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
            let mut any = false;
            for (t, &l) in mesh.tets.iter().zip(&mesh.labels) {
                if l == label {
                    any = true;
                    for &n in t {
                        lo = lo.inf(&mesh.nodes[n as usize]);
                        hi = hi.sup(&mesh.nodes[n as usize]);
                    }
                }
            }
            if !any {
                bail!(
                    "no element has the fixed label {label} (is it the brain stem's label in this image?)"
                );
            }
            (lo, hi)
        }
        FixedChoice::Bottom {
            height_m,
            half_width_m,
        } => {
            let (lo, hi) = mesh.bounds();
            let cx = 0.5 * (lo.x + hi.x);
            (
                Point3::new(cx - half_width_m, lo.y, lo.z),
                Point3::new(cx + half_width_m, hi.y, lo.z + height_m),
            )
        }
    };
    let count = mesh
        .nodes
        .iter()
        .filter(|p| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]))
        .count();
    if count < 3 {
        bail!(
            "the fixed region holds {count} nodes (at least 3 needed to hold the brain); \
             widen it (--fixed-height-mm, --fixed-half-width-mm)"
        );
    }
    Ok((lo.coords.into(), hi.coords.into(), count))
}

/// Where the two plates go: `(across_left, across_right, insertion,
/// grazing)`, m. The plates lie side by side in the mid-plane at offsets
/// along `d x n` (within 12 mm of the point, 1 mm apart at least, the left
/// one at the larger offset); their bodies at full
/// insertion (which cover every place a plate passes on its way in) are
/// sampled every 2 mm on both faces. The placement with the fewest samples
/// in the tissue wins, then the deeper, then the pair centred nearer the
/// point (depths from `insertion_m` down to 2 mm);
/// `grazing` is the fraction of samples in the tissue there (0 when both
/// plates lie in the gap).
fn fit_plates(mesh: &TetMesh, f: &FissureLandmark, insertion_m: f64) -> (f64, f64, f64, f64) {
    let (d, n) = (f.direction.into_inner(), f.normal.into_inner());
    let w = d.cross(&n);
    let probe = Probe::new(mesh, f.entry + d * (0.5 * f.depth), 0.045);
    let inside = |across: f64, insertion: f64| -> (usize, usize) {
        let (mut bad, mut all) = (0, 0);
        for i in 0..=15 {
            let s = insertion - PLATE_LENGTH_M + i as f64 * 0.002;
            for j in 0..=4 {
                let y = across - 0.5 * PLATE_WIDTH_M + j as f64 * 0.002;
                for side in [-0.5, 0.5] {
                    let p = f.entry + d * s + w * y + n * (side * PLATE_THICKNESS_M);
                    all += 1;
                    bad += usize::from(probe.inside(&p));
                }
            }
        }
        (bad, all)
    };
    // Offsets across, 1 mm apart; the pair must not overlap (1 mm apart).
    let offsets: Vec<f64> = (-12..=12).map(|k| k as f64 * 0.001).collect();
    let apart = PLATE_WIDTH_M + 0.001 - 1e-9;
    let top = insertion_m.min(f.depth).max(0.002);
    let depths = [
        top,
        0.002 + 0.66 * (top - 0.002),
        0.002 + 0.33 * (top - 0.002),
        0.002,
    ];
    let mut best: Option<(usize, f64, f64, f64, usize)> = None;
    for &depth in &depths {
        let counts: Vec<(usize, usize)> = offsets.iter().map(|&a| inside(a, depth)).collect();
        let all = counts[0].1;
        for (i, &r) in offsets.iter().enumerate() {
            for (j, &l) in offsets.iter().enumerate().skip(i) {
                if l - r < apart {
                    continue;
                }
                let bad = counts[i].0 + counts[j].0;
                let better = match best {
                    None => true,
                    Some((b, bl, br, bd, _)) => {
                        (bad, -(depth * 1e6) as i64, ((l + r).abs() * 1e6) as i64)
                            < (b, -(bd * 1e6) as i64, ((bl + br).abs() * 1e6) as i64)
                    }
                };
                if better {
                    best = Some((bad, l, r, depth, 2 * all));
                }
            }
        }
        if best.is_some_and(|b| b.0 == 0) {
            break;
        }
    }
    let (bad, l, r, depth, all) = best.expect("four depths");
    (l, r, depth, bad as f64 / all as f64)
}

/// Smooth step from 0 to 1 over `[0, 1]` (zero velocity at both ends).
fn smooth(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// The two spatulas' placements over time: insert, open, hold, close,
/// retract. Returns rows `(instrument, t, placement)` at 1 kHz.
fn open_plan(
    insertion_m: f64,
    across_m: [f64; 2],
    open_offset_m: f64,
) -> Vec<(&'static str, f64, FissurePlacement)> {
    // Phases, s: insert, settle, open, hold, close, retract.
    const PHASES: [f64; 6] = [0.6, 0.1, 1.0, 0.3, 0.5, 0.6];
    let start = -0.005;
    let total: f64 = PHASES.iter().sum();
    let steps = (total * 1000.0).round() as usize;
    let mut rows = Vec::with_capacity(2 * (steps + 1));
    for (name, sign, across) in [("left", 1.0, across_m[0]), ("right", -1.0, across_m[1])] {
        for i in 0..=steps {
            let t = i as f64 * 1e-3;
            let mut edge = 0.0;
            let mut phase = PHASES.len();
            let mut s = 0.0;
            for (k, d) in PHASES.iter().enumerate() {
                if t <= edge + d + 1e-12 {
                    phase = k;
                    s = (t - edge) / d;
                    break;
                }
                edge += d;
            }
            let (depth, open) = match phase {
                0 => (start + (insertion_m - start) * smooth(s), 0.0),
                1 => (insertion_m, 0.0),
                2 => (insertion_m, smooth(s)),
                3 => (insertion_m, 1.0),
                4 => (insertion_m, 1.0 - smooth(s)),
                _ => (insertion_m + (start - insertion_m) * smooth(s), 0.0),
            };
            rows.push((
                name,
                t,
                FissurePlacement {
                    insertion: depth,
                    across,
                    offset: sign * open * open_offset_m,
                },
            ));
        }
    }
    rows
}

fn quat_wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// Writes the scene folder (module doc) into `dir`.
pub fn write_scene(dir: &Path, req: &SceneRequest<'_>) -> anyhow::Result<SceneFiles> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let f = req.fissure.landmark;
    let (box_min, box_max, fixed_nodes) = fixed_box(req.mesh, req.fixed)?;
    let model = dir.join("model.vtu");
    fissure_server::mesh::io::write_volume(&model, req.mesh)
        .with_context(|| format!("writing {}", model.display()))?;
    let (left_m, right_m, insertion_m, grazing) = fit_plates(req.mesh, &f, req.insertion_m);
    let offset_m = FissurePlacement::into_wall(&f, PLATE_THICKNESS_M, req.push_m);
    let home = |across: f64| {
        FissurePlacement {
            insertion: -0.005,
            across,
            offset: 0.0,
        }
        .pose(&f, PLATE_LENGTH_M)
    };
    let v3 = |v: [f64; 3]| format!("[{:.7}, {:.7}, {:.7}]", v[0], v[1], v[2]);
    let q4 = |q: [f64; 4]| format!("[{}, {}, {}, {}]", q[0], q[1], q[2], q[3]);
    let open_centre = f.entry + f.direction.into_inner() * (0.5 * f.depth);
    let mut s = String::new();
    let p = req.fissure.point_m;
    writeln!(s, "name = {:?}", req.name)?;
    writeln!(
        s,
        "description = \"A brain meshed from an image; two spatulas open the fissure found near ({:.1}, {:.1}, {:.1}) mm.\"",
        p.x * 1e3,
        p.y * 1e3,
        p.z * 1e3
    )?;
    writeln!(s, "\n[model]\nkind = \"file\"\npath = \"model.vtu\"")?;
    writeln!(
        s,
        "\n# Elements of a label no tissue below names take these values (the\n\
         # bundled scenes' brain).\n[material]\nyoungs_modulus_pa = 3000.0\npoisson_ratio = {BRAIN_POISSON}"
    )?;
    for t in &req.tissues {
        writeln!(
            s,
            "\n# {}\n[[material.tissue]]\nlabel = {}\nname = {:?}\nyoungs_modulus_pa = {:.1}\npoisson_ratio = {BRAIN_POISSON}",
            t.source, t.label, t.name, t.youngs_modulus_pa
        )?;
    }
    let fixed_note = match req.fixed {
        FixedChoice::Label(l) => format!("the box of the elements of label {l} (the brain stem)"),
        FixedChoice::Bottom {
            height_m,
            half_width_m,
        } => format!(
            "the lowest {:.0} mm of the brain within {:.0} mm of its mid-sagittal plane (where the brain stem is)",
            height_m * 1e3,
            half_width_m * 1e3
        ),
    };
    writeln!(
        s,
        "\n# Held: {fixed_note}, {fixed_nodes} nodes.\n[[fixed]]\nbox_min_m = {}\nbox_max_m = {}",
        v3(box_min),
        v3(box_max)
    )?;
    writeln!(
        s,
        "\n# The brain rests on its surroundings (the bundled scenes' foundation),\n\
         # opened about the fissure so its walls move freely.\n[foundation]\n\
         stiffness_pa_per_m = 1.145e10\nopen = [\n    {{ centre_m = {}, radius_m = 0.025 }},\n]",
        v3(open_centre.coords.into())
    )?;
    if let Some(d) = req.roi_m {
        writeln!(
            s,
            "\n# Only the tissue within {:.0} mm of the fissure's point is simulated;\n\
             # the cut through the brain there is held.\n[roi]\ncentre_m = {}\ndistance_m = {d}",
            d * 1e3,
            v3(p.coords.into())
        )?;
    }
    writeln!(
        s,
        "\n[solver]\nstrategy = \"compliance\"\n\n[collision]\nmethod = \"bvh\"\nhistory = \"force-rate\"\n\n\
         [loops]\ndeformation_interval_s = 0.02"
    )?;
    writeln!(
        s,
        "\n# The fissure: entry {} m, depth direction {}, mid-plane normal {},\n\
         # gap {:.2} mm, depth {:.1} mm (sheetness {:.1}).",
        v3(f.entry.coords.into()),
        v3(f.direction.into_inner().into()),
        v3(f.normal.into_inner().into()),
        f.width * 1e3,
        f.depth * 1e3,
        req.fissure.sheetness
    )?;
    for (name, across) in [("left", left_m), ("right", right_m)] {
        let pose = home(across);
        writeln!(
            s,
            "\n[[instrument]]\nname = {name:?}\nshape = \"flat\"\nthickness_m = {PLATE_THICKNESS_M}\n\
             width_m = {PLATE_WIDTH_M}\nlength_m = {PLATE_LENGTH_M}\nnodes_per_face = 150\nrim = true\n\
             home_position_m = {}\nhome_orientation = {}",
            v3(pose.translation.vector.into()),
            q4(quat_wxyz(&pose.rotation))
        )?;
    }
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, &s).with_context(|| format!("writing {}", scene.display()))?;
    // Check what was written as the server will read it.
    fissure_server::scene::Scene::parse(&s, &scene.display().to_string())
        .with_context(|| format!("the scene written to {} does not parse", scene.display()))?;
    let mut csv = String::from("instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\n");
    for (name, t, placement) in open_plan(insertion_m, [left_m, right_m], offset_m) {
        let pose = placement.pose(&f, PLATE_LENGTH_M);
        let x = pose.translation.vector;
        let [qw, qx, qy, qz] = quat_wxyz(&pose.rotation);
        writeln!(
            csv,
            "{name},{t:.3},{:.7},{:.7},{:.7},{qw},{qx},{qy},{qz}",
            x.x, x.y, x.z
        )?;
    }
    let trajectory = dir.join("open.csv");
    std::fs::write(&trajectory, csv)
        .with_context(|| format!("writing {}", trajectory.display()))?;
    Ok(SceneFiles {
        model,
        scene,
        trajectory,
        fixed_box_m: (box_min, box_max),
        fixed_nodes,
        insertion_m,
        across_m: [left_m, right_m],
        grazing,
    })
}

/// Scene tools.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum SceneCommand {
    /// Make a running scene from a patient's image: mesh the brain (as
    /// `fissure mesh from-image`), find the fissure whose gap holds
    /// `--fissure-near`, and write `model.vtu`, `scene.toml` and `open.csv`
    /// (both spatulas: insert, open, hold, close, retract) into `--out`.
    /// Run it with `fissure demo --scene OUT/scene.toml --trajectory
    /// OUT/open.csv`.
    FromImage(FromImageArgs),
}

/// Arguments of `fissure scene from-image`.
#[derive(Debug, Clone, clap::Args)]
pub struct FromImageArgs {
    /// NIfTI-1 or NIfTI-2 images (.nii or .nii.gz): one label map (with
    /// --labels), one mask, or probability maps summed and thresholded
    /// (grey matter first, then white matter: their labels are 1 and 2).
    #[arg(value_name = "IMAGE", required = true, num_args = 1..)]
    pub images: Vec<PathBuf>,
    /// The labels of a label map that are brain (comma-separated).
    #[arg(long, value_name = "L,L,...", value_delimiter = ',', num_args = 1..)]
    pub labels: Option<Vec<u32>>,
    /// Threshold on the summed images when no --labels are given.
    #[arg(long, value_name = "T", default_value_t = 0.5)]
    pub threshold: f64,
    /// Tetrahedron size at the surface, mm.
    #[arg(long, value_name = "MM", default_value_t = 2.0)]
    pub spacing_mm: f64,
    /// Grading levels of the interior (0: uniform).
    #[arg(long, value_name = "N", default_value_t = 2)]
    pub levels: u32,
    /// A point in the gap of the fissure to open, scanner coordinates in mm
    /// (RAS+, as the image's affine gives them): three numbers.
    #[arg(
        long,
        value_name = "MM",
        num_args = 3,
        required = true,
        allow_negative_numbers = true
    )]
    pub fissure_near: Vec<f64>,
    /// Output folder (created).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Scene name (default: the output folder's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Hold the elements of this label (the brain stem of a label map: 16
    /// in FreeSurfer's and SynthSeg's tables). Default: 16 when a label map
    /// has it, else the bottom of the brain (--fixed-height-mm,
    /// --fixed-half-width-mm).
    #[arg(long, value_name = "L")]
    pub fixed_label: Option<u32>,
    /// Height of the held bottom of the brain, mm.
    #[arg(long, value_name = "MM", default_value_t = 10.0)]
    pub fixed_height_mm: f64,
    /// Half-width (along x, about the mid-sagittal plane) of the held
    /// bottom of the brain, mm.
    #[arg(long, value_name = "MM", default_value_t = 15.0)]
    pub fixed_half_width_mm: f64,
    /// A tissue's material, `LABEL=NAME:E_PA` (repeatable), replacing the
    /// defaults: for two probability maps 1 = grey matter (1389 Pa) and 2 =
    /// white matter (1895 Pa); for a label map FreeSurfer's cortex (3, 42,
    /// 8, 47: grey) and white matter (2, 41, 7, 46: white) where present
    /// (Budday et al. 2015); other labels take 3000 Pa.
    #[arg(long, value_name = "LABEL=NAME:E_PA")]
    pub tissue: Vec<String>,
    /// How far the spatulas' tips go past the fissure's entry, mm (at most
    /// the depth found).
    #[arg(long, value_name = "MM", default_value_t = 20.0)]
    pub insertion_mm: f64,
    /// How far each spatula pushes its wall beyond the gap, mm.
    #[arg(long, value_name = "MM", default_value_t = 2.0)]
    pub push_mm: f64,
    /// Simulate only the tissue within this distance of the fissure's point
    /// (mm; the cut through the brain is held): a whole brain at the
    /// meshing resolution is far more than a real-time step can solve.
    /// 0: the whole brain.
    #[arg(long, value_name = "MM", default_value_t = 30.0)]
    pub roi_mm: f64,
}

/// What `fissure scene from-image` made.
#[derive(Debug, Clone)]
pub struct SceneFromImage {
    /// The mesh and its figures.
    pub meshed: crate::mesh_cmd::ImageReport,
    /// The fissure found.
    pub fissure: FoundFissure,
    /// The files written.
    pub files: SceneFiles,
    /// The tissues of the scene.
    pub tissues: Vec<SceneTissue>,
}

const BUDDAY: &str = "Budday et al., J. Mech. Behav. Biomed. Mater. 46 (2015) 318-330: \
                      indentation, mean modulus";

/// A tissue of Budday et al. 2015 (`name`, modulus `e_pa`) on `label`.
fn budday(label: u32, name: &str, e_pa: f64) -> SceneTissue {
    SceneTissue {
        label,
        name: name.into(),
        youngs_modulus_pa: e_pa,
        source: format!(
            "{}{}: {BUDDAY} {:.3} kPa.",
            name[..1].to_uppercase(),
            &name[1..],
            e_pa * 1e-3
        ),
    }
}

fn grey(label: u32) -> SceneTissue {
    budday(label, "grey matter", GREY_MATTER_PA)
}

fn white(label: u32) -> SceneTissue {
    budday(label, "white matter", WHITE_MATTER_PA)
}

/// Parses `LABEL=NAME:E_PA`.
fn parse_tissue(s: &str) -> anyhow::Result<SceneTissue> {
    let bad = || anyhow::anyhow!("--tissue {s:?}: expected LABEL=NAME:E_PA, e.g. 3=cortex:1389");
    let (label, rest) = s.split_once('=').ok_or_else(bad)?;
    let (name, e) = rest.rsplit_once(':').ok_or_else(bad)?;
    let label: u32 = label.trim().parse().map_err(|_| bad())?;
    let e: f64 = e.trim().parse().map_err(|_| bad())?;
    if !(e.is_finite() && e > 0.0) {
        bail!("--tissue {s:?}: Young's modulus {e} Pa is not positive");
    }
    Ok(SceneTissue {
        label,
        name: name.trim().to_owned(),
        youngs_modulus_pa: e,
        source: format!("{}: given on the command line.", name.trim()),
    })
}

/// Meshes the images, finds the fissure and writes the scene folder.
pub fn from_image(args: &FromImageArgs) -> anyhow::Result<SceneFromImage> {
    let [x, y, z] = <[f64; 3]>::try_from(args.fissure_near.as_slice())
        .map_err(|_| anyhow::anyhow!("--fissure-near takes three numbers (mm)"))?;
    if ![x, y, z].iter().all(|v| v.is_finite()) {
        bail!("--fissure-near must be finite, got {x} {y} {z}");
    }
    for (flag, v) in [
        ("--fixed-height-mm", args.fixed_height_mm),
        ("--fixed-half-width-mm", args.fixed_half_width_mm),
        ("--insertion-mm", args.insertion_mm),
    ] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{flag} must be a positive length in mm, got {v}");
        }
    }
    if !(args.roi_mm.is_finite() && args.roi_mm >= 0.0) {
        bail!(
            "--roi-mm must be a distance in mm (0: the whole brain), got {}",
            args.roi_mm
        );
    }
    if !(args.push_mm.is_finite() && args.push_mm >= 0.0) {
        bail!(
            "--push-mm must be a length in mm (0 or more), got {}",
            args.push_mm
        );
    }
    let meshed = crate::mesh_cmd::from_image(
        &args.images,
        &crate::mesh_cmd::FromImageOptions {
            labels: args.labels.clone(),
            threshold: args.threshold,
            spacing_mm: args.spacing_mm,
            levels: args.levels,
        },
    )?;
    let mesh = &meshed.mesh;
    let present = |l: u32| mesh.labels.contains(&l);
    let tissues: Vec<SceneTissue> = if !args.tissue.is_empty() {
        args.tissue
            .iter()
            .map(|t| parse_tissue(t))
            .collect::<anyhow::Result<_>>()?
    } else if args.labels.is_some() {
        [3, 42, 8, 47]
            .into_iter()
            .filter(|&l| present(l))
            .map(grey)
            .chain(
                [2, 41, 7, 46]
                    .into_iter()
                    .filter(|&l| present(l))
                    .map(white),
            )
            .collect()
    } else if args.images.len() == 2 {
        [grey(1), white(2)]
            .into_iter()
            .filter(|t| present(t.label))
            .collect()
    } else {
        Vec::new()
    };
    if let Some(t) = tissues.iter().find(|t| !present(t.label)) {
        bail!(
            "--tissue: label {} ({}) is on no element of the mesh",
            t.label,
            t.name
        );
    }
    let fixed = match (args.fixed_label, &args.labels) {
        (Some(l), _) => FixedChoice::Label(l),
        (None, Some(_)) if present(16) => FixedChoice::Label(16),
        _ => FixedChoice::Bottom {
            height_m: args.fixed_height_mm * 1e-3,
            half_width_m: args.fixed_half_width_mm * 1e-3,
        },
    };
    let near = Point3::new(x, y, z) * 1e-3;
    fissure_server::progress::stage(format_args!(
        "finding the fissure near ({x:.1}, {y:.1}, {z:.1}) mm"
    ));
    let fissure = fissure_server::mesh::fissure::locate(
        mesh,
        near,
        &fissure_server::mesh::fissure::FissureOptions::default(),
    )?;
    let name = args.name.clone().unwrap_or_else(|| {
        args.out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "from-image".into())
    });
    let files = write_scene(
        &args.out,
        &SceneRequest {
            name,
            mesh,
            fissure,
            fixed,
            tissues: tissues.clone(),
            insertion_m: args.insertion_mm * 1e-3,
            push_m: args.push_mm * 1e-3,
            roi_m: (args.roi_mm > 0.0).then_some(args.roi_mm * 1e-3),
        },
    )?;
    Ok(SceneFromImage {
        meshed,
        fissure,
        files,
        tissues,
    })
}

/// Runs a `fissure scene` command and prints what it made.
pub fn run(cmd: SceneCommand) -> anyhow::Result<()> {
    match cmd {
        SceneCommand::FromImage(args) => {
            let made = from_image(&args)?;
            print!("{}", made.meshed.table());
            let f = made.fissure.landmark;
            let mm = |p: [f64; 3]| {
                format!(
                    "({:.1}, {:.1}, {:.1}) mm",
                    p[0] * 1e3,
                    p[1] * 1e3,
                    p[2] * 1e3
                )
            };
            let unit = |v: nalgebra::Vector3<f64>| format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z);
            println!(
                "fissure: entry {}, depth {:.1} mm along {}, gap {:.2} mm, plane normal {} (sheetness {:.1})",
                mm(f.entry.coords.into()),
                f.depth * 1e3,
                unit(f.direction.into_inner()),
                f.width * 1e3,
                unit(f.normal.into_inner()),
                made.fissure.sheetness
            );
            if f.width < PLATE_THICKNESS_M + 0.0005 {
                println!(
                    "note: the gap ({:.2} mm) is narrower than the spatula ({:.1} mm) plus 0.5 mm: \
                     the plates start against the walls (a finer --spacing-mm resolves the gap better)",
                    f.width * 1e3,
                    PLATE_THICKNESS_M * 1e3
                );
            }
            for t in &made.tissues {
                println!(
                    "tissue {}: {} E = {:.0} Pa",
                    t.label, t.name, t.youngs_modulus_pa
                );
            }
            println!(
                "spatulas: side by side {:.1} and {:.1} mm across the fissure's point, tips {:.1} mm past the entry",
                made.files.across_m[0] * 1e3,
                made.files.across_m[1] * 1e3,
                made.files.insertion_m * 1e3
            );
            if made.files.grazing > 0.0 {
                println!(
                    "note: {:.0} % of the spatulas' body lies in the tissue at full insertion (the fissure curves \
                     or narrows within their width): they push the walls from the start; a point deeper in the \
                     fissure, or a finer --spacing-mm, may give them room",
                    made.files.grazing * 100.0
                );
            }
            let (lo, hi) = made.files.fixed_box_m;
            println!(
                "held: {} nodes in the box {} to {}",
                made.files.fixed_nodes,
                mm(lo),
                mm(hi)
            );
            println!(
                "wrote {}, {}, {}",
                made.files.model.display(),
                made.files.scene.display(),
                made.files.trajectory.display()
            );
            println!(
                "run it: fissure demo --scene {} --trajectory {}",
                made.files.scene.display(),
                made.files.trajectory.display()
            );
            Ok(())
        }
    }
}
