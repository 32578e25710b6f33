//! `fissure scene from-image`: a running scene from a patient's image: the
//! brain meshed from the image (`fissure mesh from-image`), the fissure
//! found near a point the user gives ([`fissure_engine::mesh::fissure`]),
//! and a scene folder a demo runs as it is.
//!
//! The folder holds `model.vtu` (the labelled mesh, scanner coordinates in
//! m), `scene.toml` (a material per tissue with its source, the fixed
//! region, the foundation opened about the fissure, two spatulas at home
//! outside the fissure's entry) and `open.csv` (both spatulas: insert, open
//! the fissure, hold, close, retract; the `instrument,t_s,...` trajectory
//! set of [`crate::client::trajectory`]). `fissure demo --scene DIR/scene.toml
//! --trajectory DIR/open.csv` runs it.

use anyhow::{Context, bail};
use fissure_engine::collide::FissurePlacement;
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::fissure::{FoundFissure, Probe};
use fissure_engine::mesh::phantom::FissureLandmark;
use nalgebra::{Point3, Unit, UnitQuaternion};
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
/// Widths tried, widest first: the bundled plate, then narrower spatulas
/// (micro-dissection spatulas are 2 to 10 mm wide) where a patient's
/// fissure has no room for it.
const PLATE_WIDTHS_M: [f64; 4] = [0.008, 0.006, 0.004, 0.003];
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
    /// The plates' plane's turn from the fissure's mid-plane about its depth
    /// direction and about the across axis, degrees.
    pub turn_deg: [f64; 2],
    /// The spatulas' width, m (the widest of [`PLATE_WIDTHS_M`] that fits).
    pub width_m: f64,
    /// How far the left and right plate move from the plane to open
    /// (to first touch of their wall plus the push), m.
    pub open_m: [f64; 2],
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

/// Where the two plates go, found by [`fit_plates`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct PlateFit {
    /// The plates' frame: the fissure's landmark turned and shifted so that
    /// the plates lie in the gap (entry, depth direction, mid-plane normal).
    frame: FissureLandmark,
    /// The plates' width, m.
    width_m: f64,
    /// Offsets of the left and right plate across (along `d x n`), m.
    across_m: [f64; 2],
    /// Depth the tips reach past the entry, m.
    insertion_m: f64,
    /// Fraction of the plates' body samples in the tissue at full insertion.
    grazing: f64,
    /// The frame's turn from the landmark's: about the depth direction and
    /// about the across axis, rad.
    turn_rad: [f64; 2],
    /// Distance from the left plate's `+n` face to its wall and from the
    /// right plate's `-n` face to its wall (the least over the face), m.
    clearance_m: [f64; 2],
}

/// The landmark turned by `roll` about its depth direction and `pitch`
/// about `d x n`, about the point `pivot_m` past the entry, and shifted
/// `shift_m` along the new normal.
fn turned(
    f: &FissureLandmark,
    roll: f64,
    pitch: f64,
    pivot_m: f64,
    shift_m: f64,
) -> FissureLandmark {
    let (d, n) = (f.direction, f.normal);
    let w = Unit::new_normalize(d.cross(&n));
    let r = UnitQuaternion::from_axis_angle(&w, pitch) * UnitQuaternion::from_axis_angle(&d, roll);
    let (d2, n2) = (r * d, r * n);
    let pivot = f.entry + d.into_inner() * pivot_m;
    FissureLandmark {
        entry: pivot - d2.into_inner() * pivot_m + n2.into_inner() * shift_m,
        direction: d2,
        normal: n2,
        ..*f
    }
}

/// Where the two plates go. The plates lie side by side in a plane through
/// the fissure at offsets along `d x n` (within 12 mm, 1 mm apart at least,
/// the left one at the larger offset); their bodies at full insertion
/// (which cover every place a plate passes on its way in) are sampled every
/// a quarter of their width across and 2 mm along, on both faces. Tried in
/// turn: the tips' depth, from `insertion_m` (capped at the fissure's depth)
/// down to 2 mm; at each depth the widths of [`PLATE_WIDTHS_M`], widest
/// first; and for each the plane turned by up to 15 degrees about the depth direction and about the
/// across axis (5-degree steps) and shifted up to 1.5 mm along its normal
/// (a fissure curves and its gap is not centred on one plane). The first
/// depth and width at which some placement has no sample in the tissue
/// take the least turned of those, then the pair centred nearer the point; failing
/// that everywhere, the placement with the fewest samples in the tissue
/// ([`PlateFit::grazing`] says how many).
fn fit_plates(mesh: &TetMesh, f: &FissureLandmark, insertion_m: f64) -> PlateFit {
    let probe = Probe::new(
        mesh,
        f.entry + f.direction.into_inner() * (0.5 * f.depth),
        0.045,
    );
    let face_points = |g: &FissureLandmark, width: f64, across: f64, insertion: f64, side: f64| {
        let (d, n) = (g.direction.into_inner(), g.normal.into_inner());
        let (w, e) = (d.cross(&n), g.entry);
        (0..=15).flat_map(move |i| {
            let s = insertion - PLATE_LENGTH_M + i as f64 * 0.002;
            (0..=4).map(move |j| {
                let y = across + width * (0.25 * j as f64 - 0.5);
                e + d * s + w * y + n * (side * 0.5 * PLATE_THICKNESS_M)
            })
        })
    };
    let inside = |g: &FissureLandmark, width: f64, across: f64, insertion: f64| -> usize {
        [-1.0, 1.0]
            .iter()
            .flat_map(|&side| face_points(g, width, across, insertion, side))
            .filter(|p| probe.inside(p))
            .count()
    };
    let samples = 2 * 16 * 5;
    let offsets: Vec<f64> = (-12..=12).map(|k| k as f64 * 0.001).collect();
    let top = insertion_m.min(f.depth).max(0.002);
    let depths = [
        top,
        0.002 + 0.66 * (top - 0.002),
        0.002 + 0.33 * (top - 0.002),
        0.002,
    ];
    let angles: Vec<f64> = (-3..=3).map(|k| (5.0 * k as f64).to_radians()).collect();
    let mut frames: Vec<(f64, f64, f64)> = Vec::new();
    for &roll in &angles {
        for &pitch in &angles {
            for k in -3..=3 {
                frames.push((roll, pitch, k as f64 * 0.0005));
            }
        }
    }
    // Least turned (then least shifted) first.
    frames.sort_by(|a, b| {
        (a.0.abs() + a.1.abs(), a.2.abs())
            .partial_cmp(&(b.0.abs() + b.1.abs(), b.2.abs()))
            .unwrap()
    });
    // ((samples in the tissue, turn + shift rank, centring), fit)
    let mut best: Option<((usize, usize, f64), PlateFit)> = None;
    'search: for &depth in &depths {
        for &width in &PLATE_WIDTHS_M {
            let apart = width + 0.001 - 1e-9;
            for (rank, &(roll, pitch, shift)) in frames.iter().enumerate() {
                let g = turned(f, roll, pitch, 0.5 * depth, shift);
                let counts: Vec<usize> = offsets
                    .iter()
                    .map(|&a| inside(&g, width, a, depth))
                    .collect();
                for (i, &r) in offsets.iter().enumerate() {
                    for (j, &l) in offsets.iter().enumerate().skip(i) {
                        if l - r < apart {
                            continue;
                        }
                        let key = (counts[i] + counts[j], rank, (l + r).abs());
                        if best.as_ref().is_none_or(|b| key < b.0) {
                            best = Some((
                                key,
                                PlateFit {
                                    frame: g,
                                    width_m: width,
                                    across_m: [l, r],
                                    insertion_m: depth,
                                    grazing: key.0 as f64 / (2 * samples) as f64,
                                    turn_rad: [roll, pitch],
                                    clearance_m: [0.0; 2],
                                },
                            ));
                        }
                    }
                }
                if best.as_ref().is_some_and(|b| b.0.0 == 0) {
                    break 'search;
                }
            }
        }
    }
    let mut fit = best.expect("four depths").1;
    // How far each plate's pushing face is from its wall: marched in
    // 0.1 mm steps (up to 10 mm) from every sample of the face.
    for (k, side) in [(0, 1.0), (1, -1.0)] {
        let n = fit.frame.normal.into_inner() * side;
        fit.clearance_m[k] = face_points(
            &fit.frame,
            fit.width_m,
            fit.across_m[k],
            fit.insertion_m,
            side,
        )
        .map(|p| {
            (0..=100)
                .map(|s| s as f64 * 1e-4)
                .find(|&t| probe.inside(&(p + n * t)))
                .unwrap_or(0.01)
        })
        .fold(f64::INFINITY, f64::min);
    }
    fit
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
    open_offset_m: [f64; 2],
) -> Vec<(&'static str, f64, FissurePlacement)> {
    // Phases, s: insert, settle, open, hold, close, retract.
    const PHASES: [f64; 6] = [0.6, 0.1, 1.0, 0.3, 0.5, 0.6];
    let start = -0.005;
    let total: f64 = PHASES.iter().sum();
    let steps = (total * 1000.0).round() as usize;
    let mut rows = Vec::with_capacity(2 * (steps + 1));
    for (name, sign, across, open_offset_m) in [
        ("left", 1.0, across_m[0], open_offset_m[0]),
        ("right", -1.0, across_m[1], open_offset_m[1]),
    ] {
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
    fissure_engine::mesh::io::write_volume(&model, req.mesh)
        .with_context(|| format!("writing {}", model.display()))?;
    let fit = fit_plates(req.mesh, &f, req.insertion_m);
    let [left_m, right_m] = fit.across_m;
    // Each plate pushes its wall `push_m` beyond first touch.
    let offset_m = fit.clearance_m.map(|c| c + req.push_m);
    let frame = fit.frame;
    let home = |across: f64| {
        FissurePlacement {
            insertion: -0.005,
            across,
            offset: 0.0,
        }
        .pose(&frame, PLATE_LENGTH_M)
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
    writeln!(
        s,
        "# The spatulas' plane: that mid-plane turned {:.0} deg about the depth direction\n\
         # and {:.0} deg about the across axis, entry {} m, so that both lie in the gap\n\
         # ({:.0} % of their body in the tissue at full insertion).",
        fit.turn_rad[0].to_degrees(),
        fit.turn_rad[1].to_degrees(),
        v3(frame.entry.coords.into()),
        fit.grazing * 100.0
    )?;
    for (name, across) in [("left", left_m), ("right", right_m)] {
        let pose = home(across);
        writeln!(
            s,
            "\n[[instrument]]\nname = {name:?}\nshape = \"flat\"\nthickness_m = {PLATE_THICKNESS_M}\n\
             width_m = {}\nlength_m = {PLATE_LENGTH_M}\nnodes_per_face = 150\nrim = true\n\
             home_position_m = {}\nhome_orientation = {}",
            fit.width_m,
            v3(pose.translation.vector.into()),
            q4(quat_wxyz(&pose.rotation))
        )?;
    }
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, &s).with_context(|| format!("writing {}", scene.display()))?;
    // Check what was written as the server will read it.
    fissure_engine::scene::Scene::parse(&s, &scene.display().to_string())
        .with_context(|| format!("the scene written to {} does not parse", scene.display()))?;
    let mut csv = String::from("instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\n");
    for (name, t, placement) in open_plan(fit.insertion_m, [left_m, right_m], offset_m) {
        let pose = placement.pose(&frame, PLATE_LENGTH_M);
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
        insertion_m: fit.insertion_m,
        across_m: [left_m, right_m],
        grazing: fit.grazing,
        turn_deg: fit.turn_rad.map(f64::to_degrees),
        width_m: fit.width_m,
        open_m: offset_m,
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
    #[arg(value_name = "IMAGE", required_unless_present = "mesh", num_args = 1..)]
    pub images: Vec<PathBuf>,
    /// Use this labelled mesh (`model.vtu` of an earlier scene, or the output
    /// of `fissure mesh from-image`) instead of meshing images: to try
    /// another fissure point without meshing again. Its labels are taken
    /// as grey (1) and white (2) matter unless --labels or --tissue say
    /// otherwise.
    #[arg(long, value_name = "MODEL.vtu", conflicts_with = "images")]
    pub mesh: Option<PathBuf>,
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
    /// How far each spatula pushes its wall beyond first touch, mm.
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
    /// The image's figures (none when the mesh was read from a file).
    pub meshed: Option<crate::lab::mesh::ImageReport>,
    /// The mesh, m, with a tissue label per tetrahedron.
    pub mesh: TetMesh,
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
    let (meshed, mesh) = match &args.mesh {
        Some(path) => {
            fissure_engine::progress::stage(format_args!("reading {}", path.display()));
            let mesh = fissure_engine::mesh::io::read_volume(path)
                .with_context(|| format!("reading the mesh {}", path.display()))?;
            (None, mesh)
        }
        None => {
            let mut report = crate::lab::mesh::from_image(
                &args.images,
                &crate::lab::mesh::FromImageOptions {
                    labels: args.labels.clone(),
                    threshold: args.threshold,
                    spacing_mm: args.spacing_mm,
                    levels: args.levels,
                },
            )?;
            let empty = TetMesh {
                nodes: Vec::new(),
                tets: Vec::new(),
                labels: Vec::new(),
            };
            let mesh = std::mem::replace(&mut report.mesh, empty);
            (Some(report), mesh)
        }
    };
    let owned = mesh;
    let mesh = &owned;
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
    } else if args.images.len() == 2 || args.mesh.is_some() {
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
    fissure_engine::progress::stage(format_args!(
        "finding the fissure near ({x:.1}, {y:.1}, {z:.1}) mm"
    ));
    let fissure = fissure_engine::mesh::fissure::locate(
        mesh,
        near,
        &fissure_engine::mesh::fissure::FissureOptions::default(),
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
        mesh: owned,
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
            match &made.meshed {
                Some(m) => print!("{}", m.table()),
                None => println!(
                    "mesh: {} nodes, {} tetrahedra",
                    made.mesh.nodes.len(),
                    made.mesh.tets.len()
                ),
            }
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
                "spatulas ({:.0} mm wide): side by side {:.1} and {:.1} mm across the fissure's point, tips {:.1} mm past the entry, \
                 in the mid-plane turned {:.0} and {:.0} deg (about the depth direction, about the across axis); \
                 they open {:.2} and {:.2} mm",
                made.files.width_m * 1e3,
                made.files.across_m[0] * 1e3,
                made.files.across_m[1] * 1e3,
                made.files.insertion_m * 1e3,
                made.files.turn_deg[0],
                made.files.turn_deg[1],
                made.files.open_m[0] * 1e3,
                made.files.open_m[1] * 1e3,
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
