//! Scene files (TOML): what a scene models, and nothing more.
//!
//! A scene names the brain model, the material, the fixed region, the solver
//! strategy, the collision method, the contact law, the loops and the
//! instruments. Optional
//! parts (the skull, a region of interest) are only built when present: the
//! server computes only what a scene requires.
//!
//! Scenes ship embedded in the binary (`cube`, `sylvian`, `interhemispheric`,
//! `v-valley`, `u-valley`); a path to a `.toml` file loads a user's scene.
//! Every value is checked by [`Scene::validate`]; an error names the field
//! (`instrument[1].thickness_m`) and what is wrong with it.

pub mod assessment;
pub mod region;
mod serde_fields;
pub mod ties;

use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The scenes embedded in the binary, by name.
pub const EMBEDDED: &[(&str, &str)] = &[
    ("sylvian", include_str!("../../scenes/sylvian.toml")),
    (
        "sylvian-204k",
        include_str!("../../scenes/sylvian-204k.toml"),
    ),
    (
        "sylvian-arachnoid",
        include_str!("../../scenes/sylvian-arachnoid.toml"),
    ),
    (
        "interhemispheric",
        include_str!("../../scenes/interhemispheric.toml"),
    ),
    ("cube", include_str!("../../scenes/cube.toml")),
    ("v-valley", include_str!("../../scenes/v-valley.toml")),
    ("u-valley", include_str!("../../scenes/u-valley.toml")),
];

/// The default scene.
pub const DEFAULT_SCENE: &str = "sylvian";

/// Errors in loading a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// Neither an embedded scene name nor a readable file.
    #[error("unknown scene '{name}': not an embedded scene ({known}) and not a readable file")]
    Unknown { name: String, known: String },
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// TOML syntax or an unknown/mistyped key: where (line and column,
    /// 1-based) and what; the TOML error, with the offending line quoted,
    /// is the source.
    #[error("scene {origin}: {at}{message}")]
    Parse {
        origin: String,
        /// `line L, column C: `, or empty where the error has no place.
        at: String,
        message: String,
        #[source]
        source: Box<toml::de::Error>,
    },
    /// A value is out of range or inconsistent.
    #[error("scene {origin}: field `{field}`: {reason}")]
    Invalid {
        origin: String,
        field: String,
        reason: String,
    },
    /// The scene asks for a part this build was compiled without.
    #[error(
        "scene {origin}: field `{field}`: {value} needs the `{feature}` feature of the engine (fissure-engine; on by default in fissure-server and fissure-cli), which this build was compiled without (build with `--features {feature}`)"
    )]
    NotBuilt {
        origin: String,
        field: &'static str,
        value: &'static str,
        feature: &'static str,
    },
}

/// A scene: everything the server models.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Scene name.
    pub name: String,
    /// What the scene models, in a sentence.
    #[serde(default)]
    pub description: String,
    /// The brain model.
    pub model: ModelSpec,
    /// The tissue material.
    pub material: MaterialSpec,
    /// Regions whose nodes are fixed (a union).
    #[serde(default)]
    pub fixed: Vec<Region>,
    /// The deformation solver.
    #[serde(default)]
    pub solver: SolverSpec,
    /// The collision pipeline.
    #[serde(default)]
    pub collision: CollisionSpec,
    /// The contact mechanics.
    #[serde(default)]
    pub contact: ContactSpec,
    /// Loop rates and safety thresholds.
    #[serde(default)]
    pub loops: LoopSpec,
    /// The instruments (spatulas).
    #[serde(rename = "instrument", deserialize_with = "instrument_tables")]
    pub instruments: Vec<InstrumentSpec>,
    /// The skull, when modelled.
    #[serde(default)]
    pub skull: Option<SkullSpec>,
    /// An elastic foundation on the outer surface, when modelled.
    #[serde(default)]
    pub foundation: Option<FoundationSpec>,
    /// A region of interest: when present, the FEM runs only on the tissue
    /// within `distance_m` of it, with the cut surface fixed (a speed option).
    #[serde(default)]
    pub roi: Option<RoiSpec>,
    /// The connective tissue across the fissure (`[[ties]]`,
    /// [`ties`]): trabeculae and bridging vessels. Needs the `compliance`
    /// or `direct` strategy.
    #[serde(default)]
    pub ties: Vec<ties::TieSpec>,
    /// The thresholds the session's injury measures are scored against
    /// (`[assessment]`, [`assessment`]); the cited defaults when absent.
    #[serde(default)]
    pub assessment: assessment::AssessmentSpec,
}

/// A region of interest around the working fissure.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RoiSpec {
    /// A point of the fissure, m.
    pub centre_m: [f64; 3],
    /// When given, the distance is measured to the plane through `centre_m`
    /// with this normal (e.g. the fissure's mid-plane) instead of to the point.
    #[serde(default)]
    pub plane_normal: Option<[f64; 3]>,
    /// Tissue farther than this is cropped away, m.
    pub distance_m: f64,
}

/// An elastic (Winkler) foundation on the outer surface: normal springs of
/// `stiffness_pa_per_m` between the tissue and a fixed support, on every
/// outer triangle except those of the `open` regions (see [`region`] and
/// [`crate::fem::foundation`]). Every strategy takes it (the nonlinear ones
/// add the springs' energy, force and tangent, `Model::foundation`).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FoundationSpec {
    /// Normal stiffness per area, Pa/m (N/m per m^2), > 0.
    pub stiffness_pa_per_m: f64,
    /// Regions left without springs (the craniotomy window, the fissure
    /// walls): a triangle is open when its centroid lies in a box, sphere
    /// or landmark, or when its three nodes are in a vertex list.
    #[serde(default)]
    pub open: Vec<Region>,
}

/// The finest phantom lattice spacing a scene may ask for, m.
pub const MIN_PHANTOM_SPACING_M: f64 = 0.002;
/// The coarsest phantom lattice spacing a scene may ask for, m.
pub const MAX_PHANTOM_SPACING_M: f64 = 0.012;

/// Whether `h` (m) is a phantom lattice spacing a model may ask for: the
/// lattice must resolve a 3 mm fissure (the mesher's own bound) and stay
/// within memory (2 mm with the proven mesher is about 1.6 million
/// tetrahedra).
pub fn phantom_spacing_allowed(h: f64) -> bool {
    h.is_finite() && (MIN_PHANTOM_SPACING_M..=MAX_PHANTOM_SPACING_M).contains(&h)
}

/// Which brain model to build.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ModelSpec {
    /// A cube `[0, size]^3` with `cells` cells per edge (six tets a cell).
    Cube {
        /// Edge length, m.
        size_m: f64,
        /// Cells per edge.
        cells: usize,
    },
    /// The paper's V-shaped valley block (60 x 30 x 30 mm).
    VValley,
    /// The paper's U-shaped valley block (60 x 30 x 30 mm).
    UValley,
    /// The procedural brain phantom at a named preset.
    Phantom {
        /// Preset name, e.g. `paper-48k`.
        preset: String,
        /// Mesh it with the proven mesher (surface at the fissure spacing
        /// everywhere, interior graded, dihedral angles within the proven
        /// bounds; 3 to 4 times the elements). Default false.
        #[serde(default)]
        proven: bool,
        /// Finest lattice spacing, m, in place of the preset's (with
        /// `proven`, the spacing of the whole surface): refines or coarsens
        /// the preset's mesh while keeping its shape, fissures and grading
        /// (`paper-48k`: 4 mm; the element count grows about as
        /// `spacing^-3` with `proven`). Must resolve the fissures: a
        /// spacing above the fissure gap is refused or gives a mesh whose
        /// fissure walls touch. Default: the preset's.
        #[serde(default)]
        spacing_m: Option<f64>,
        /// Uniform refinements of the meshed phantom (each tetrahedron into
        /// eight at its edge midpoints, [`crate::mesh::refine`]): the same
        /// shape, surface and landmarks at half the element size each, 8x
        /// the tetrahedra. At most
        /// [`MAX_REFINEMENTS`](crate::mesh::refine::MAX_REFINEMENTS).
        /// Default 0.
        #[serde(default)]
        refine: u32,
        /// Local refinements after `refine`, a ball or a list of balls
        /// applied in order: every tetrahedron whose centroid lies in the
        /// ball split into eight at its edge midpoints, its neighbours split
        /// into two or four so that the mesh stays conforming
        /// ([`crate::mesh::refine::local`]); the shape is kept exactly.
        /// Finer where the spatulas press at a fraction of a uniform
        /// refinement's cost. Nest a later ball well inside an earlier one
        /// (by a few elements): the closure's split elements at an earlier
        /// ball's rim should not be split again. Default: none.
        #[serde(default, deserialize_with = "one_or_many")]
        refine_near: Vec<SphereSpec>,
    },
    /// A tetrahedral mesh file (MSH, VTK/VTU, TetGen), relative to the scene
    /// file. Its boundary must be a closed manifold, and it must be at most
    /// 1 m across once scaled.
    File {
        /// Path to the mesh.
        path: PathBuf,
        /// Factor from the file's unit to metres (0.001 for a file in
        /// millimetres). Default 1.
        #[serde(default = "unit_scale")]
        scale: f64,
    },
}

fn unit_scale() -> f64 {
    1.0
}

/// Tissue material: one for the whole brain, or one per tissue label of a
/// labelled model (`[[material.tissue]]`, for a mesh made from a label
/// image); elements whose label no tissue names take the top-level values.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Young's modulus, Pa.
    pub youngs_modulus_pa: f64,
    /// Poisson's ratio, in [0, 0.5).
    pub poisson_ratio: f64,
    /// A material per tissue label of the model (`[[material.tissue]]`).
    #[serde(default, rename = "tissue")]
    pub tissues: Vec<TissueSpec>,
}

/// The material of one tissue of a labelled model.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TissueSpec {
    /// The tissue's label in the model file (the `.vtu` cell data `label`).
    pub label: u32,
    /// A name for reports ("grey matter").
    #[serde(default)]
    pub name: String,
    /// Young's modulus, Pa.
    pub youngs_modulus_pa: f64,
    /// Poisson's ratio, in [0, 0.5).
    pub poisson_ratio: f64,
}

impl MaterialSpec {
    /// The solver's materials: the default and one per tissue.
    pub fn to_fem(&self) -> (crate::fem::Material, Vec<crate::fem::Tissue>) {
        let m = |e, nu| crate::fem::Material {
            youngs_modulus_pa: e,
            poisson_ratio: nu,
        };
        (
            m(self.youngs_modulus_pa, self.poisson_ratio),
            self.tissues
                .iter()
                .map(|t| crate::fem::Tissue {
                    label: t.label,
                    material: m(t.youngs_modulus_pa, t.poisson_ratio),
                })
                .collect(),
        )
    }
}

/// A region of nodes.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(untagged, deny_unknown_fields)]
pub enum Region {
    /// Nodes inside an axis-aligned box (bounds included), m.
    Box {
        /// Lower corner, m.
        box_min_m: [f64; 3],
        /// Upper corner, m.
        box_max_m: [f64; 3],
    },
    /// Nodes inside a sphere, m.
    Sphere {
        /// Centre, m.
        centre_m: [f64; 3],
        /// Radius, m.
        radius_m: f64,
    },
    /// A region the model names: the phantom's `brain-stem` (a sphere),
    /// `sylvian-left`, `sylvian-right` and `interhemispheric` (a fissure's
    /// walls and floor: within half its width plus 1 mm of its mid-plane,
    /// from its entry to its floor).
    Landmark {
        /// Landmark name.
        landmark: String,
    },
    /// The volume nodes listed in a file (one 0-based index a line, `#`
    /// comments), relative to the scene file; for a user's mesh.
    /// `foundation.open` and `skull.surface.open` only.
    Vertices {
        /// Path to the list.
        vertices_file: PathBuf,
    },
}

impl Region {
    /// Whether a point (m) lies in the region; landmarks are resolved by the
    /// model and answer `false` here.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        match self {
            Region::Box {
                box_min_m: lo,
                box_max_m: hi,
            } => (0..3).all(|i| p[i] >= lo[i] && p[i] <= hi[i]),
            Region::Sphere {
                centre_m: c,
                radius_m: r,
            } => (0..3).map(|i| (p[i] - c[i]).powi(2)).sum::<f64>() <= r * r,
            Region::Landmark { .. } | Region::Vertices { .. } => false,
        }
    }
}

pub use crate::fem::{Element, Strategy};

fn de_element<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Element, D::Error> {
    let s = String::deserialize(d)?;
    s.parse().map_err(serde::de::Error::custom)
}

fn de_strategy<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Strategy, D::Error> {
    let s = String::deserialize(d)?;
    s.parse().map_err(serde::de::Error::custom)
}

/// Solver settings.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SolverSpec {
    /// Strategy: `direct`, `compliance`, `corotational` or `neo-hookean`.
    #[serde(deserialize_with = "de_strategy")]
    pub strategy: Strategy,
    /// Relative residual tolerance of the iterative strategies
    /// (`corotational`, `neo-hookean`).
    pub tolerance: f64,
    /// Most outer (Newton) iterations per step of the iterative strategies.
    pub max_iterations: u32,
    /// Element formulation: `tet4` (linear tetrahedra, the default) or
    /// `tet4-nodal-pressure` (the volumetric strain averaged over each
    /// node's star: no locking as `nu -> 0.5`; `compliance` and `direct`
    /// only).
    #[serde(deserialize_with = "de_element")]
    pub element: Element,
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            strategy: Strategy::Compliance,
            tolerance: crate::fem::corotational::IterativeOptions::INTERACTIVE_TOLERANCE,
            max_iterations: 30,
            element: Element::Tet4,
        }
    }
}

/// Ray-casting method.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum CollisionMethod {
    /// All node-triangle combinations (the paper's reference).
    Brute,
    /// A BVH over the surface, refitted each step.
    #[default]
    Bvh,
}

impl CollisionMethod {
    /// The name a scene file gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Brute => "brute",
            Self::Bvh => "bvh",
        }
    }
}

/// Where rays are cast.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum CollisionBackend {
    /// On the CPU.
    #[default]
    Cpu,
    /// On a GPU through wgpu (falls back to the CPU without an adapter).
    Gpu,
}

impl CollisionBackend {
    /// The name a scene file gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
        }
    }
}

/// When the contact history is renewed: the collision stage's own enum.
pub use crate::collide::contact::history::HistoryMode;

/// How the CPU BVH walks runs of parallel rays: the collision stage's own
/// enum.
pub use crate::collide::rays::bvh::Traversal;

/// Collision settings.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CollisionSpec {
    /// Ray-casting method.
    pub method: CollisionMethod,
    /// Ray-casting backend.
    pub backend: CollisionBackend,
    /// How the CPU BVH walks each face's run of parallel rays: once for the
    /// run (`"bundled"`, the default) or once per ray (`"per-ray"`, for
    /// comparison). The answers are the same.
    pub traversal: Traversal,
    /// History renewal.
    pub history: HistoryMode,
    /// Whether history culling (B1-B3) is applied.
    pub culling: bool,
    /// Largest depth behind a face at which a collision pair may form, m.
    /// A triangle farther behind a face than this is reached through the
    /// tissue (e.g. the far side of a block when the plate tip enters the
    /// bottom of a narrowing groove edge-first, before either face has a
    /// history), never a contact of that face. Set it above the model's size
    /// to reproduce the paper's unbounded rule.
    pub max_depth_m: f64,
}

/// Default of [`CollisionSpec::max_depth_m`], m.
pub const DEFAULT_MAX_DEPTH_M: f64 = 0.01;

impl Default for CollisionSpec {
    fn default() -> Self {
        Self {
            method: CollisionMethod::Bvh,
            backend: CollisionBackend::Cpu,
            traversal: Traversal::Bundled,
            history: HistoryMode::ForceRate,
            culling: true,
            max_depth_m: DEFAULT_MAX_DEPTH_M,
        }
    }
}

/// The mechanics of the contact between the plates and the tissue.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ContactLaw {
    /// Unilateral (Signorini) contact without friction: the tissue slides
    /// freely along the plates and never pulls them (the default).
    #[default]
    Frictionless,
    /// Unilateral contact with Coulomb friction of coefficient
    /// `friction_coefficient` (stick and slip; needs the `compliance`
    /// strategy).
    Coulomb,
    /// The paper's projection (every vertex of a paired triangle moved onto
    /// the face plane, all three components fixed), for comparison.
    Paper,
}

impl ContactLaw {
    /// All laws.
    pub const ALL: [ContactLaw; 3] = [Self::Frictionless, Self::Coulomb, Self::Paper];

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Frictionless => "frictionless",
            Self::Coulomb => "coulomb",
            Self::Paper => "paper",
        }
    }
}

/// The shape the contact search runs on (`contact.geometry`).
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum ContactGeometry {
    /// `rest` for the linear strategies with frictionless contact,
    /// `deformed` otherwise (the default).
    #[default]
    Auto,
    /// Linearized contact: candidates, pairs and polygon points from the
    /// rest surface at the instruments' poses; the gap
    /// `g = n . (x_rest - p) + n . u` is exact for any displacement, as the
    /// small-strain model is. The rows are then a function of the poses
    /// alone, so a step needs no search on its own solved shape and a force
    /// sample solves the problem a full solve at its poses solves.
    Rest,
    /// The search runs on the last solved surface and on each step's own
    /// solved shape until the rows come back the same (the geometry's
    /// fixed point); what large-deformation strategies need.
    Deformed,
}

impl ContactGeometry {
    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Rest => "rest",
            Self::Deformed => "deformed",
        }
    }
}

/// Contact settings (the `[contact]` table).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ContactSpec {
    /// The contact law.
    pub law: ContactLaw,
    /// Coulomb coefficient (`law = "coulomb"` only), >= 0.
    pub friction_coefficient: Option<f64>,
    /// Vertices up to this far in front of a face or beside its outline
    /// are candidates of the contact problem, m; each step publishes the
    /// compliance of the vertices within twice this distance for the force
    /// loops, so the plate's travel within one deformation interval should
    /// stay below it.
    pub band_m: f64,
    /// Vertices up to this far in front of a face or beside its outline
    /// have their compliance computed ahead of contact, m (>= twice
    /// `band_m`).
    pub ahead_m: f64,
    /// How far outside a face's outline a vertex may lie and still be
    /// pushed by the face, m.
    pub cover_tolerance_m: f64,
    /// The shape the contact search runs on ([`ContactGeometry`]).
    pub geometry: ContactGeometry,
}

impl Default for ContactSpec {
    fn default() -> Self {
        Self {
            law: ContactLaw::Frictionless,
            friction_coefficient: None,
            band_m: crate::collide::contact::DEFAULT_BAND_M,
            ahead_m: crate::collide::contact::DEFAULT_AHEAD_M,
            cover_tolerance_m: crate::collide::contact::DEFAULT_COVER_TOLERANCE_M,
            geometry: ContactGeometry::Auto,
        }
    }
}

/// Loops and safety.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LoopSpec {
    /// Interval between deformation steps, s. In stepped mode steps happen at
    /// multiples of it on the pose timestamps; free-running, it is the minimum
    /// period of the deformation loop.
    pub deformation_interval_s: f64,
    /// Deterministic stepped mode.
    pub stepped: bool,
    /// Nominal haptic rate, Hz.
    pub haptic_rate_hz: f64,
    /// Force magnitude above which samples are flagged, N.
    pub safe_force_n: f64,
    /// Force magnitude samples are clamped to, N.
    pub max_force_n: f64,
    /// Largest instrument travel accepted in one sample, m; larger jumps are
    /// flagged.
    pub max_jump_m: f64,
}

impl Default for LoopSpec {
    fn default() -> Self {
        Self {
            deformation_interval_s: 0.02,
            stepped: false,
            haptic_rate_hz: 1000.0,
            safe_force_n: 1.0,
            max_force_n: 8.0,
            max_jump_m: 0.01,
        }
    }
}

pub use crate::collide::tool::instrument::{LayoutKind, PlateShape};

/// One spatula.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InstrumentSpec {
    /// Name clients claim it by.
    pub name: String,
    /// The plate's outline with the parameter only it has (`shape`, and
    /// `base_width_m` for a trapezoid or `bend_radius_m` for a curved plate;
    /// read by [`instrument_tables`], whence the default here).
    #[serde(default)]
    pub shape: PlateShape,
    /// Plate thickness, m.
    pub thickness_m: f64,
    /// Plate width (at the tip for a trapezoid), m.
    pub width_m: f64,
    /// Plate length, m.
    pub length_m: f64,
    /// Source-node layout.
    #[serde(default)]
    pub layout: LayoutKind,
    /// Source nodes a face.
    pub nodes_per_face: u32,
    /// Whether rim nodes are added for contact with the side.
    #[serde(default)]
    pub rim: bool,
    /// Position of the handle point at rest, m.
    pub home_position_m: [f64; 3],
    /// Orientation at rest, quaternion (w, x, y, z).
    #[serde(default = "identity_quaternion")]
    pub home_orientation: [f64; 4],
}

/// Reads the `[[instrument]]` tables.
///
/// In a scene file a plate's shape and its parameter sit beside the
/// instrument's other fields (`shape = "curved"`, `bend_radius_m = 0.05`),
/// while [`PlateShape`] is one internally tagged enum. serde cannot flatten
/// a tagged enum into a struct that denies unknown fields, and a tagged
/// enum has no default tag, so each table is regrouped first: `shape`
/// (`"flat"` when absent) and every key that is not a field of
/// [`InstrumentSpec`] move into a `shape` sub-table, which the enum's own
/// derive reads (refusing a parameter of another shape or a missing one).
fn instrument_tables<'de, D>(d: D) -> Result<Vec<InstrumentSpec>, D::Error>
where
    D: serde::Deserializer<'de>,
{
    use serde::de::Error as _;
    let tables = Vec::<toml::Table>::deserialize(d)?;
    tables
        .into_iter()
        .enumerate()
        .map(|(i, table)| instrument_from_table(table, i).map_err(D::Error::custom))
        .collect()
}

/// One `[[instrument]]` table (the `i`th) as an [`InstrumentSpec`].
fn instrument_from_table(mut table: toml::Table, i: usize) -> Result<InstrumentSpec, String> {
    let named = match table.get("name").and_then(toml::Value::as_str) {
        Some(name) => format!("instrument {name:?}"),
        None => format!("instrument[{i}]"),
    };
    let fields = serde_fields::of::<InstrumentSpec>();
    let mut shape = toml::Table::new();
    let tag = table.remove("shape").unwrap_or_else(|| "flat".into());
    let tag_name = tag.as_str().unwrap_or_default().to_owned();
    shape.insert("shape".into(), tag);
    let params: Vec<String> = table
        .keys()
        .filter(|k| !fields.contains(&k.as_str()))
        .cloned()
        .collect();
    for key in &params {
        let value = table.remove(key).expect("key listed from the table");
        shape.insert(key.clone(), value);
    }
    let plate = PlateShape::deserialize(toml::Value::Table(shape)).map_err(|e| {
        format!(
            "{named}: {} (in shape = {tag_name:?} and its parameters; an instrument's own fields are {})",
            e.message().trim_end(),
            fields.join(", ")
        )
    })?;
    // A shape without parameters is a unit variant, whose derive ignores
    // extra keys: anything moved beside it is unknown.
    if matches!(plate, PlateShape::Flat | PlateShape::Blade) && !params.is_empty() {
        return Err(format!(
            "{named}: unknown field `{}`: shape = {tag_name:?} takes no parameter, and an instrument's own fields are {}",
            params.join("`, `"),
            fields.join(", ")
        ));
    }
    let mut spec = InstrumentSpec::deserialize(toml::Value::Table(table))
        .map_err(|e| format!("{named}: {}", e.message().trim_end()))?;
    spec.shape = plate;
    Ok(spec)
}

/// A table or an array of tables (read as TOML first, so that a bad field
/// is named by the ball's own reader rather than lost in an untagged
/// enum's "no variant matched").
fn one_or_many<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Vec<SphereSpec>, D::Error> {
    use serde::de::Error;
    match toml::Value::deserialize(de)? {
        toml::Value::Array(v) => v
            .into_iter()
            .map(|b| SphereSpec::deserialize(b).map_err(D::Error::custom))
            .collect(),
        b => Ok(vec![SphereSpec::deserialize(b).map_err(D::Error::custom)?]),
    }
}

fn identity_quaternion() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}

/// The skull: a rigid surface around the brain, the paper's unilateral
/// spheres, or both.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkullSpec {
    /// Nodes may not leave this sphere.
    #[serde(default)]
    pub containing: Option<SphereSpec>,
    /// Nodes may not enter this sphere.
    #[serde(default)]
    pub excluding: Option<SphereSpec>,
    /// The brain's outer surface offset outward by a CSF gap: a rigid skull
    /// the tissue slides along (frictionless, unilateral), open where named.
    #[serde(default)]
    pub surface: Option<SkullSurfaceSpec>,
}

/// Default of [`SkullSurfaceSpec::csf_gap_m`], m.
pub const DEFAULT_CSF_GAP_M: f64 = 0.0015;

/// The skull as the rest outer surface offset outward by the CSF layer
/// ([`crate::fem::skull::SkullSurface`]).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkullSurfaceSpec {
    /// Thickness of the CSF layer between the brain and the skull, m
    /// (default 1.5 mm).
    #[serde(default = "default_csf_gap_m")]
    pub csf_gap_m: f64,
    /// How close to the skull a supported node must be, m, to take part in
    /// a step's contact problem from its first solve (default
    /// [`Self::band_m`]'s: half the CSF gap, at most `contact.band_m`). A
    /// node beyond it that the solved shape pushes through the skull joins
    /// the problem in the step's next solve (the frictionless answer is
    /// unique, so the band sets the work, not the answer): a band as wide
    /// as a thin gap would put every supported node in every step.
    #[serde(default)]
    pub band_m: Option<f64>,
    /// Regions with no skull (the craniotomy window, the fissure's walls): a
    /// surface node inside one of them is free to move outward.
    #[serde(default)]
    pub open: Vec<Region>,
}

fn default_csf_gap_m() -> f64 {
    DEFAULT_CSF_GAP_M
}

impl SkullSurfaceSpec {
    /// The skull's own contact band, m: `band_m` when given, else half the
    /// CSF gap, at most `contact_band_m`.
    pub fn band_m(&self, contact_band_m: f64) -> f64 {
        self.band_m
            .unwrap_or_else(|| (0.5 * self.csf_gap_m).min(contact_band_m))
    }
}

/// A sphere.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SphereSpec {
    /// Centre, m.
    pub centre_m: [f64; 3],
    /// Radius, m.
    pub radius_m: f64,
}

impl Scene {
    /// The contact geometry the scene runs: `contact.geometry`, with `auto`
    /// resolved (rest for `direct` and `compliance` with frictionless
    /// contact, deformed otherwise: friction drags the tissue along the
    /// plate, millimetres on a slide, and which tissue the plate covers
    /// must then be found on the dragged shape, not the rest one).
    pub fn contact_geometry(&self) -> ContactGeometry {
        match self.contact.geometry {
            ContactGeometry::Auto => {
                if self.solver.strategy.is_linear() && self.contact.law == ContactLaw::Frictionless
                {
                    ContactGeometry::Rest
                } else {
                    ContactGeometry::Deformed
                }
            }
            g => g,
        }
    }

    /// Loads an embedded scene by name, or a scene file by path.
    pub fn load(name_or_path: &str) -> Result<(Scene, Option<PathBuf>), SceneError> {
        if let Some((_, text)) = EMBEDDED.iter().find(|(n, _)| *n == name_or_path) {
            return Ok((Self::parse(text, name_or_path)?, None));
        }
        let path = Path::new(name_or_path);
        if !path.is_file() {
            return Err(SceneError::Unknown {
                name: name_or_path.to_owned(),
                known: EMBEDDED
                    .iter()
                    .map(|(n, _)| *n)
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.to_owned(),
            source,
        })?;
        let mut scene = Self::parse(&text, &path.display().to_string())?;
        let dir = path.parent().unwrap_or(Path::new("."));
        if let ModelSpec::File { path: mesh, .. } = &mut scene.model {
            if mesh.is_relative() {
                *mesh = dir.join(&*mesh);
            }
        }
        let skull_open = scene
            .skull
            .as_mut()
            .and_then(|s| s.surface.as_mut())
            .map(|s| &mut s.open);
        let foundation_open = scene.foundation.as_mut().map(|f| &mut f.open);
        for open in [foundation_open, skull_open].into_iter().flatten() {
            for r in open.iter_mut() {
                if let Region::Vertices { vertices_file } = r {
                    if vertices_file.is_relative() {
                        *vertices_file = dir.join(&*vertices_file);
                    }
                }
            }
        }
        for t in &mut scene.ties {
            if let Some(Region::Vertices { vertices_file }) = &mut t.region {
                if vertices_file.is_relative() {
                    *vertices_file = dir.join(&*vertices_file);
                }
            }
            if let Some(p) = &mut t.pairs_file {
                if p.is_relative() {
                    *p = dir.join(&*p);
                }
            }
        }
        Ok((scene, Some(path.to_owned())))
    }

    /// Parses and validates scene text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Scene, SceneError> {
        let scene: Scene = toml::from_str(text).map_err(|source| {
            let at = source.span().map_or(String::new(), |span| {
                let before = &text[..span.start.min(text.len())];
                let line = before.matches('\n').count() + 1;
                let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
                format!("line {line}, column {column}: ")
            });
            SceneError::Parse {
                origin: origin.to_owned(),
                at,
                message: source.message().trim_end().to_owned(),
                source: Box::new(source),
            }
        })?;
        scene.validate(origin)?;
        Ok(scene)
    }

    /// Checks that this build has every part the scene asks for: the GPU
    /// collision backend needs the `gpu` feature.
    pub fn check_built(&self, origin: &str) -> Result<(), SceneError> {
        if self.collision.backend == CollisionBackend::Gpu && !cfg!(feature = "gpu") {
            return Err(SceneError::NotBuilt {
                origin: origin.to_owned(),
                field: "collision.backend",
                value: "\"gpu\"",
                feature: "gpu",
            });
        }
        Ok(())
    }

    /// Checks every value; the error names the first bad field.
    pub fn validate(&self, origin: &str) -> Result<(), SceneError> {
        self.check_built(origin)?;
        let bad = |field: String, reason: String| SceneError::Invalid {
            origin: origin.to_owned(),
            field,
            reason,
        };
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(
                    field.to_owned(),
                    format!("must be a finite positive number, got {v}"),
                ))
            }
        };
        let finite3 = |field: String, v: &[f64]| {
            if v.iter().all(|c| c.is_finite()) {
                Ok(())
            } else {
                Err(bad(field, format!("must be finite, got {v:?}")))
            }
        };
        if let ModelSpec::File { scale, .. } = &self.model {
            crate::mesh::units::check_scale(*scale, "model.scale")
                .map_err(|reason| bad("model.scale".into(), reason))?;
        }
        if let ModelSpec::Cube { size_m, cells } = &self.model {
            positive("model.size_m", *size_m)?;
            if !(1..=64).contains(cells) {
                return Err(bad(
                    "model.cells".into(),
                    format!("must be in 1..=64, got {cells}"),
                ));
            }
        }
        if let ModelSpec::Phantom { refine, .. } = &self.model
            && *refine > crate::mesh::refine::MAX_REFINEMENTS
        {
            return Err(bad(
                "model.refine".into(),
                format!(
                    "must be at most {} (each refinement multiplies the tetrahedra by 8), got {refine}",
                    crate::mesh::refine::MAX_REFINEMENTS
                ),
            ));
        }
        if let ModelSpec::Phantom { refine_near, .. } = &self.model {
            for (i, b) in refine_near.iter().enumerate() {
                finite3(format!("model.refine_near[{i}].centre_m"), &b.centre_m)?;
                positive(&format!("model.refine_near[{i}].radius_m"), b.radius_m)?;
            }
        }
        if let ModelSpec::Phantom {
            spacing_m: Some(h), ..
        } = &self.model
        {
            if !phantom_spacing_allowed(*h) {
                return Err(bad(
                    "model.spacing_m".into(),
                    format!(
                        "must be within {MIN_PHANTOM_SPACING_M} to {MAX_PHANTOM_SPACING_M} m, got {h}"
                    ),
                ));
            }
        }
        let materials = std::iter::once((
            "material".to_string(),
            &self.material.youngs_modulus_pa,
            &self.material.poisson_ratio,
        ))
        .chain(self.material.tissues.iter().enumerate().map(|(i, t)| {
            (
                format!("material.tissue[{i}]"),
                &t.youngs_modulus_pa,
                &t.poisson_ratio,
            )
        }));
        for (at, &e, &nu) in materials {
            positive(&format!("{at}.youngs_modulus_pa"), e)?;
            if !(nu.is_finite() && (0.0..0.5).contains(&nu)) {
                return Err(bad(
                    format!("{at}.poisson_ratio"),
                    format!("must be in [0, 0.5), got {nu}"),
                ));
            }
        }
        for (i, t) in self.material.tissues.iter().enumerate() {
            if let Some(j) = self.material.tissues[..i]
                .iter()
                .position(|u| u.label == t.label)
            {
                return Err(bad(
                    format!("material.tissue[{i}].label"),
                    format!("label {} is already given by material.tissue[{j}]", t.label),
                ));
            }
        }
        let check_region = |at: String, r: &Region| -> Result<(), SceneError> {
            match r {
                Region::Box {
                    box_min_m,
                    box_max_m,
                } => {
                    finite3(format!("{at}.box_min_m"), box_min_m)?;
                    finite3(format!("{at}.box_max_m"), box_max_m)?;
                    if (0..3).any(|k| box_min_m[k] > box_max_m[k]) {
                        return Err(bad(at, "box_min_m exceeds box_max_m".into()));
                    }
                }
                Region::Sphere { centre_m, radius_m } => {
                    finite3(format!("{at}.centre_m"), centre_m)?;
                    positive(&format!("{at}.radius_m"), *radius_m)?;
                }
                Region::Landmark { .. } | Region::Vertices { .. } => {}
            }
            Ok(())
        };
        for (i, r) in self.fixed.iter().enumerate() {
            if matches!(r, Region::Vertices { .. }) {
                return Err(bad(
                    format!("fixed[{i}]"),
                    "a vertex list is accepted in foundation.open and skull.surface.open only"
                        .into(),
                ));
            }
            check_region(format!("fixed[{i}]"), r)?;
        }
        if let Some(f) = &self.foundation {
            positive("foundation.stiffness_pa_per_m", f.stiffness_pa_per_m)?;
            for (i, r) in f.open.iter().enumerate() {
                check_region(format!("foundation.open[{i}]"), r)?;
            }
        }
        if !self.solver.strategy.takes_element(self.solver.element) {
            return Err(bad(
                "solver.element".into(),
                format!(
                    "{:?} needs solver.strategy = \"compliance\", \"direct\" or \"neo-hookean\" (the scene has {:?})",
                    self.solver.element.name(),
                    self.solver.strategy.name()
                ),
            ));
        }
        positive("collision.max_depth_m", self.collision.max_depth_m)?;
        positive("contact.band_m", self.contact.band_m)?;
        positive("contact.ahead_m", self.contact.ahead_m)?;
        if self.contact.ahead_m < 2.0 * self.contact.band_m {
            return Err(bad(
                "contact.ahead_m".into(),
                format!(
                    "must be at least twice contact.band_m ({} m), got {}",
                    self.contact.band_m, self.contact.ahead_m
                ),
            ));
        }
        let tol = self.contact.cover_tolerance_m;
        if !(tol.is_finite() && tol >= 0.0) {
            return Err(bad(
                "contact.cover_tolerance_m".into(),
                format!("must be a finite number >= 0, got {tol}"),
            ));
        }
        if self.contact.geometry == ContactGeometry::Rest {
            if !self.solver.strategy.is_linear() {
                return Err(bad(
                    "contact.geometry".into(),
                    format!(
                        "\"rest\" linearizes the contact about the rest shape, as only the linear strategies (\"compliance\", \"direct\") do their elasticity; the scene has {:?} (use \"deformed\")",
                        self.solver.strategy.name()
                    ),
                ));
            }
            match self.contact.law {
                ContactLaw::Paper => {
                    return Err(bad(
                        "contact.geometry".into(),
                        "the paper's rule projects onto the deformed surface; \"rest\" needs law = \"frictionless\"".into(),
                    ));
                }
                ContactLaw::Coulomb => {
                    return Err(bad(
                        "contact.geometry".into(),
                        "friction drags the tissue along the plate (millimetres on a slide), so which tissue the plate covers must be found on the dragged shape; \"rest\" needs law = \"frictionless\" (use \"deformed\")".into(),
                    ));
                }
                ContactLaw::Frictionless => {}
            }
        }
        match (self.contact.law, self.contact.friction_coefficient) {
            (ContactLaw::Coulomb, None) => {
                return Err(bad(
                    "contact.friction_coefficient".into(),
                    "law = \"coulomb\" needs a friction coefficient".into(),
                ));
            }
            (ContactLaw::Coulomb, Some(mu)) => {
                if !(mu.is_finite() && mu >= 0.0) {
                    return Err(bad(
                        "contact.friction_coefficient".into(),
                        format!("must be a finite number >= 0, got {mu}"),
                    ));
                }
                if self.solver.strategy != Strategy::Compliance {
                    return Err(bad(
                        "contact.law".into(),
                        format!(
                            "coulomb friction needs solver.strategy = \"compliance\" (the scene has {:?})",
                            self.solver.strategy.name()
                        ),
                    ));
                }
            }
            (law, Some(_)) => {
                return Err(bad(
                    "contact.friction_coefficient".into(),
                    format!(
                        "is read only with law = \"coulomb\" (the scene has law = {:?})",
                        law.name()
                    ),
                ));
            }
            (_, None) => {}
        }
        positive("solver.tolerance", self.solver.tolerance)?;
        if self.solver.max_iterations == 0 {
            return Err(bad(
                "solver.max_iterations".into(),
                "must be at least 1".into(),
            ));
        }
        positive(
            "loops.deformation_interval_s",
            self.loops.deformation_interval_s,
        )?;
        positive("loops.haptic_rate_hz", self.loops.haptic_rate_hz)?;
        positive("loops.safe_force_n", self.loops.safe_force_n)?;
        positive("loops.max_force_n", self.loops.max_force_n)?;
        positive("loops.max_jump_m", self.loops.max_jump_m)?;
        if self.instruments.is_empty() {
            return Err(bad(
                "instrument".into(),
                "the scene needs at least one instrument".into(),
            ));
        }
        for (i, ins) in self.instruments.iter().enumerate() {
            let f = |name: &str| format!("instrument[{i}].{name}");
            if ins.name.is_empty()
                || !ins
                    .name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(bad(
                    f("name"),
                    format!(
                        "must be non-empty letters, digits, '-' or '_', got {:?}",
                        ins.name
                    ),
                ));
            }
            if self.instruments[..i].iter().any(|o| o.name == ins.name) {
                return Err(bad(
                    f("name"),
                    format!("duplicate instrument name {:?}", ins.name),
                ));
            }
            positive(&f("thickness_m"), ins.thickness_m)?;
            positive(&f("width_m"), ins.width_m)?;
            positive(&f("length_m"), ins.length_m)?;
            if !(1..=4096).contains(&ins.nodes_per_face) {
                return Err(bad(
                    f("nodes_per_face"),
                    format!("must be in 1..=4096, got {}", ins.nodes_per_face),
                ));
            }
            match ins.shape {
                PlateShape::Trapezoid { base_width_m } => {
                    positive(&f("base_width_m"), base_width_m)?
                }
                PlateShape::Curved { bend_radius_m } => {
                    positive(&f("bend_radius_m"), bend_radius_m)?
                }
                PlateShape::Flat | PlateShape::Blade => {}
            }
            finite3(f("home_position_m"), &ins.home_position_m)?;
            let q = ins.home_orientation;
            let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
            if !(norm.is_finite() && (norm - 1.0).abs() < 1e-3) {
                return Err(bad(
                    f("home_orientation"),
                    format!("must be a unit quaternion (w, x, y, z), got {q:?}"),
                ));
            }
        }
        if let Some(roi) = &self.roi {
            finite3("roi.centre_m".into(), &roi.centre_m)?;
            positive("roi.distance_m", roi.distance_m)?;
            if let Some(n) = roi.plane_normal {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if !(len.is_finite() && len > 1e-12) {
                    return Err(bad(
                        "roi.plane_normal".into(),
                        format!("must be a non-zero vector, got {n:?}"),
                    ));
                }
            }
        }
        if let Some(skull) = &self.skull {
            for (name, s) in [
                ("containing", &skull.containing),
                ("excluding", &skull.excluding),
            ] {
                if let Some(s) = s {
                    finite3(format!("skull.{name}.centre_m"), &s.centre_m)?;
                    positive(&format!("skull.{name}.radius_m"), s.radius_m)?;
                }
            }
            if let Some(s) = &skull.surface {
                positive("skull.surface.csf_gap_m", s.csf_gap_m)?;
                if let Some(b) = s.band_m {
                    positive("skull.surface.band_m", b)?;
                }
                for (i, r) in s.open.iter().enumerate() {
                    check_region(format!("skull.surface.open[{i}]"), r)?;
                }
            }
        }
        self.assessment
            .check()
            .map_err(|(field, reason)| bad(field, reason))?;
        for (i, t) in self.ties.iter().enumerate() {
            let at = format!("ties[{i}]");
            t.check(&at).map_err(|(field, reason)| bad(field, reason))?;
            if let Some(r) = &t.region {
                check_region(format!("{at}.region"), r)?;
            }
        }
        Ok(())
    }

    /// The instrument named `name`.
    pub fn instrument(&self, name: &str) -> Option<(usize, &InstrumentSpec)> {
        self.instruments
            .iter()
            .enumerate()
            .find(|(_, i)| i.name == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The contact geometry: `auto` is the rest shape for the linear
    /// strategies with frictionless contact and the deformed one otherwise;
    /// `rest` with a large-deformation strategy, with friction or with the
    /// paper's rule is refused, naming the field.
    #[test]
    fn the_contact_geometry_follows_the_strategy_and_rest_is_refused_where_it_does_not_hold() {
        let cube = include_str!("../../scenes/cube.toml");
        let with = |strategy: &str, contact: &str| {
            let text = cube.replace(
                "strategy = \"compliance\"",
                &format!("strategy = \"{strategy}\""),
            );
            Scene::parse(&format!("{text}\n[contact]\n{contact}\n"), "c.toml")
        };
        let geometry = |strategy: &str, contact: &str| {
            with(strategy, contact)
                .map(|s| s.contact_geometry())
                .map_err(|e| e.to_string())
        };
        assert_eq!(geometry("compliance", ""), Ok(ContactGeometry::Rest));
        assert_eq!(geometry("direct", ""), Ok(ContactGeometry::Rest));
        assert_eq!(geometry("neo-hookean", ""), Ok(ContactGeometry::Deformed));
        assert_eq!(geometry("corotational", ""), Ok(ContactGeometry::Deformed));
        assert_eq!(
            geometry("compliance", "law = \"paper\""),
            Ok(ContactGeometry::Deformed)
        );
        assert_eq!(
            geometry("compliance", "geometry = \"deformed\""),
            Ok(ContactGeometry::Deformed)
        );
        assert_eq!(
            geometry(
                "compliance",
                "law = \"coulomb\"\nfriction_coefficient = 0.3"
            ),
            Ok(ContactGeometry::Deformed)
        );
        for (strategy, contact) in [
            ("neo-hookean", "geometry = \"rest\""),
            ("compliance", "law = \"paper\"\ngeometry = \"rest\""),
            (
                "compliance",
                "law = \"coulomb\"\nfriction_coefficient = 0.3\ngeometry = \"rest\"",
            ),
        ] {
            let err = geometry(strategy, contact).unwrap_err();
            assert!(err.contains("contact.geometry"), "{strategy}: {err}");
        }
    }

    /// A plate's outline is its shape with the one parameter that shape has:
    /// each shape reads back under its own name with its parameter, the
    /// plate it gives is that shape's, and a parameter of another shape, a missing
    /// one or a bad value is refused naming the instrument and the field.
    #[test]
    fn a_shape_takes_its_own_parameter_and_refuses_another_shapes() {
        let cube = include_str!("../../scenes/cube.toml");
        let with = |shape: &str| {
            let text = cube.replacen("shape = \"flat\"", shape, 1);
            Scene::parse(&text, "c.toml").map_err(|e| e.to_string())
        };
        let scene = with("shape = \"trapezoid\"\nbase_width_m = 0.014").unwrap();
        let left = &scene.instruments[0];
        assert_eq!(
            left.shape,
            PlateShape::Trapezoid {
                base_width_m: 0.014
            }
        );
        assert_eq!(left.shape.name(), "trapezoid");
        let plate = left
            .shape
            .plate(left.thickness_m, left.width_m, left.length_m);
        assert_eq!((plate.base_width, plate.tip_width), (0.014, 0.010));
        let scene = with("shape = \"curved\"\nbend_radius_m = 0.05").unwrap();
        let left = &scene.instruments[0];
        assert_eq!(left.shape.name(), "curved");
        let plate = left
            .shape
            .plate(left.thickness_m, left.width_m, left.length_m);
        assert_eq!(plate.bend_radius, Some(0.05));
        assert_eq!(
            with("shape = \"flat\"").unwrap().instruments[0]
                .shape
                .name(),
            "flat"
        );
        assert_eq!(with("").unwrap().instruments[0].shape, PlateShape::Flat);
        for (shape, field) in [
            ("shape = \"flat\"\nbase_width_m = 0.014", "base_width_m"),
            ("shape = \"flat\"\nbend_radius_m = 0.05", "bend_radius_m"),
            ("shape = \"trapezoid\"", "base_width_m"),
            ("shape = \"curved\"", "bend_radius_m"),
            (
                "shape = \"curved\"\nbend_radius_m = 0.05\nbase_width_m = 0.01",
                "base_width_m",
            ),
            (
                "shape = \"trapezoid\"\nbase_width_m = 0.014\nbend_radius_m = 0.05",
                "bend_radius_m",
            ),
            (
                "shape = \"trapezoid\"\nbase_width_m = -0.01",
                "instrument[0].base_width_m",
            ),
            (
                "shape = \"curved\"\nbend_radius_m = 0.0",
                "instrument[0].bend_radius_m",
            ),
        ] {
            let err = with(shape).unwrap_err();
            assert!(err.contains(field), "{shape}: {err}");
        }
        assert!(
            with("shape = \"trapezoid\"")
                .unwrap_err()
                .contains("\"left\"")
        );
        // A key that is neither a field nor the shape's parameter is named,
        // with the fields an instrument has.
        for shape in ["", "shape = \"trapezoid\"\nbase_width_m = 0.014"] {
            let err = with(&format!("{shape}\nwidht_m = 0.01")).unwrap_err();
            assert!(err.contains("widht_m"), "{err}");
            assert!(err.contains("thickness_m, width_m"), "{err}");
        }
        let err = with("shape = \"oval\"").unwrap_err();
        assert!(err.contains("`oval`") && err.contains("`curved`"), "{err}");
    }

    #[test]
    fn embedded_scenes_parse() {
        for (name, _) in EMBEDDED {
            let (scene, path) = Scene::load(name).unwrap();
            assert!(path.is_none());
            assert!(!scene.instruments.is_empty(), "{name}");
        }
    }

    #[test]
    fn a_phantom_model_can_ask_for_the_proven_mesher() {
        let text = include_str!("../../scenes/sylvian.toml");
        let (default, _) = Scene::load("sylvian").unwrap();
        assert!(matches!(
            default.model,
            ModelSpec::Phantom { proven: false, .. }
        ));
        let asked = text.replace(
            "preset = \"paper-48k\"",
            "preset = \"coarse\"\nproven = true",
        );
        assert_ne!(asked, text);
        let scene = Scene::parse(&asked, "p.toml").unwrap();
        assert_eq!(
            scene.model,
            ModelSpec::Phantom {
                preset: "coarse".into(),
                proven: true,
                spacing_m: None,
                refine: 0,
                refine_near: Vec::new(),
            }
        );
        let model = crate::sim::core::engine::Model::build(&scene).unwrap();
        let (lo, hi) = crate::mesh::stuffing::dihedral_range(&model.mesh);
        assert!(
            lo >= crate::mesh::stuffing::PROVEN_MIN_DIHEDRAL_DEG
                && hi <= crate::mesh::stuffing::PROVEN_MAX_DIHEDRAL_DEG,
            "{lo} .. {hi}"
        );
        let plain = crate::mesh::phantom::preset("coarse").unwrap().mesh;
        assert_ne!(model.mesh.tets.len(), plain.tets.len());
    }

    /// The `sylvian` scene on the coarse phantom, with `extra` lines added
    /// to its `[model]`.
    fn coarse_sylvian_with(extra: &str) -> String {
        include_str!("../../scenes/sylvian.toml").replace(
            "preset = \"paper-48k\"",
            &format!("preset = \"coarse\"\n{extra}"),
        )
    }

    /// A finer spacing refines the preset's mesh (more elements, smaller
    /// mean element) and keeps it a valid phantom; a spacing outside the
    /// allowed range is refused, naming the field and the bound.
    #[test]
    fn a_phantom_spacing_refines_the_mesh_and_out_of_range_ones_are_refused() {
        let with = coarse_sylvian_with;
        let plain = Scene::parse(&with(""), "p.toml").unwrap();
        let fine = Scene::parse(&with("spacing_m = 0.009"), "p.toml").unwrap();
        assert!(matches!(
            fine.model,
            ModelSpec::Phantom {
                spacing_m: Some(h),
                ..
            } if h == 0.009
        ));
        let plain = crate::sim::core::engine::Model::build(&plain).unwrap();
        let fine = crate::sim::core::engine::Model::build(&fine).unwrap();
        // The surface (most of the coarse phantom's elements) grows as
        // the spacing's inverse square: (12 / 9)^2 = 1.8.
        assert!(
            10 * fine.mesh.tets.len() > 13 * plain.mesh.tets.len(),
            "{} against {}",
            fine.mesh.tets.len(),
            plain.mesh.tets.len()
        );
        for bad in ["0.001", "0.05", "-0.004", "nan"] {
            let e = Scene::parse(&with(&format!("spacing_m = {bad}")), "p.toml").unwrap_err();
            let msg = e.to_string();
            assert!(msg.contains("model.spacing_m"), "{bad}: {msg}");
        }
    }

    /// The skull's own band defaults to half the CSF gap, never beyond the
    /// contact band; a given one is kept, and one that is not a positive
    /// length is refused, naming the field.
    #[test]
    fn the_skull_band_defaults_to_half_the_gap_and_a_bad_one_is_named() {
        let cube = include_str!("../../scenes/cube.toml");
        let parse =
            |extra: &str| Scene::parse(&format!("{cube}\n[skull.surface]\n{extra}"), "s.toml");
        let band = |extra: &str| {
            let scene = parse(extra).unwrap();
            let surface = scene.skull.as_ref().unwrap().surface.as_ref().unwrap();
            surface.band_m(scene.contact.band_m)
        };
        assert_eq!(band("csf_gap_m = 0.0002"), 0.0001);
        // Half of 3 mm is beyond the 1 mm contact band.
        assert_eq!(
            band("csf_gap_m = 0.003"),
            crate::collide::contact::DEFAULT_BAND_M
        );
        assert_eq!(band("csf_gap_m = 0.0002\nband_m = 0.00005"), 0.00005);
        for bad in ["0", "-1e-4", "nan", "inf"] {
            let msg = parse(&format!("band_m = {bad}")).unwrap_err().to_string();
            assert!(msg.contains("skull.surface.band_m"), "{bad}: {msg}");
        }
    }

    /// `model.refine_near` refines the tetrahedra in its ball (and a
    /// conforming closure), keeps the volume, and names a bad ball's field.
    #[test]
    fn a_phantom_refined_near_a_point_keeps_its_volume_and_a_bad_ball_is_named() {
        let with = coarse_sylvian_with;
        let plain = Scene::parse(&with(""), "p.toml").unwrap();
        let near = Scene::parse(
            &with("refine_near = { centre_m = [-0.0532, 0.010, 0.0], radius_m = 0.02 }"),
            "p.toml",
        )
        .unwrap();
        let plain = crate::sim::core::engine::Model::build(&plain).unwrap();
        let near = crate::sim::core::engine::Model::build(&near).unwrap();
        let (n0, n1) = (plain.mesh.tets.len(), near.mesh.tets.len());
        assert!(n1 > n0 && n1 < 8 * n0, "{n1} against {n0}");
        let volume = |m: &crate::mesh::TetMesh| -> f64 {
            (0..m.tets.len()).map(|t| m.signed_volume(t)).sum()
        };
        let (v0, v1) = (volume(&plain.mesh), volume(&near.mesh));
        assert!((v1 - v0).abs() <= 1e-12 * v0, "{v1} vs {v0}");
        // Two nested balls: finer again within the inner one.
        let twice = Scene::parse(
            &with("refine_near = [{ centre_m = [-0.0532, 0.010, 0.0], radius_m = 0.02 }, { centre_m = [-0.0532, 0.010, 0.0], radius_m = 0.01 }]"),
            "p.toml",
        )
        .unwrap();
        let twice = crate::sim::core::engine::Model::build(&twice).unwrap();
        assert!(
            twice.mesh.tets.len() > n1,
            "{} against {n1}",
            twice.mesh.tets.len()
        );
        let v2 = volume(&twice.mesh);
        assert!((v2 - v0).abs() <= 1e-12 * v0, "{v2} vs {v0}");
        let typo = Scene::parse(
            &with("refine_near = { centre_m = [0.0, 0.0, 0.0], radius = 0.01 }"),
            "p.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(typo.contains("radius"), "{typo}");
        for (bad, field) in [
            (
                "refine_near = { centre_m = [0.0, 0.0, 0.0], radius_m = 0.0 }",
                "model.refine_near[0].radius_m",
            ),
            (
                "refine_near = { centre_m = [0.0, nan, 0.0], radius_m = 0.01 }",
                "model.refine_near[0].centre_m",
            ),
        ] {
            let msg = Scene::parse(&with(bad), "p.toml").unwrap_err().to_string();
            assert!(msg.contains(field), "{bad}: {msg}");
        }
    }

    /// `model.refine` splits every tetrahedron of the meshed phantom into
    /// eight and keeps its shape (the same volume, the brain stem still
    /// held); more than the allowed refinements are refused, naming the
    /// field.
    #[test]
    fn a_refined_phantom_keeps_its_shape_with_eight_times_the_elements() {
        let with = coarse_sylvian_with;
        let plain = Scene::parse(&with(""), "p.toml").unwrap();
        let refined = Scene::parse(&with("refine = 1"), "p.toml").unwrap();
        let plain = crate::sim::core::engine::Model::build(&plain).unwrap();
        let refined = crate::sim::core::engine::Model::build(&refined).unwrap();
        assert_eq!(refined.mesh.tets.len(), 8 * plain.mesh.tets.len());
        let volume = |m: &crate::mesh::TetMesh| -> f64 {
            (0..m.tets.len()).map(|t| m.signed_volume(t)).sum()
        };
        let (v0, v1) = (volume(&plain.mesh), volume(&refined.mesh));
        assert!((v1 - v0).abs() <= 1e-10 * v0, "{v1} vs {v0}");
        // The fixed region holds the old nodes and the new ones between.
        assert!(refined.fixed.len() > plain.fixed.len());
        let e = Scene::parse(&with("refine = 3"), "p.toml").unwrap_err();
        assert!(e.to_string().contains("model.refine"), "{e}");
    }

    #[test]
    fn a_gpu_scene_loads_only_where_the_gpu_backend_is_built() {
        let text = include_str!("../../scenes/v-valley.toml");
        let gpu = text.replace(
            "method = \"bvh\"\n",
            "method = \"bvh\"\nbackend = \"gpu\"\n",
        );
        assert_ne!(gpu, text);
        let parsed = Scene::parse(&gpu, "v.toml");
        if cfg!(feature = "gpu") {
            assert_eq!(parsed.unwrap().collision.backend, CollisionBackend::Gpu);
        } else {
            let e = parsed.unwrap_err();
            assert!(
                matches!(
                    e,
                    SceneError::NotBuilt {
                        field: "collision.backend",
                        feature: "gpu",
                        ..
                    }
                ),
                "{e:?}"
            );
            assert!(e.to_string().contains("`gpu` feature"), "{e}");
        }
    }

    #[test]
    fn tissue_materials_parse_and_bad_ones_name_their_entry() {
        let text = include_str!("../../scenes/cube.toml");
        let with = |tissues: &str| {
            text.replace(
                "poisson_ratio = 0.45\n",
                &format!("poisson_ratio = 0.45\n{tissues}"),
            )
        };
        let two = "\n[[material.tissue]]\nlabel = 1\nname = \"grey matter\"\n\
                   youngs_modulus_pa = 1390.0\npoisson_ratio = 0.45\n\
                   \n[[material.tissue]]\nlabel = 2\nname = \"white matter\"\n\
                   youngs_modulus_pa = 1895.0\npoisson_ratio = 0.45\n";
        let good = with(two);
        assert_ne!(good, text);
        let scene = Scene::parse(&good, "t.toml").unwrap();
        let (default, tissues) = scene.material.to_fem();
        assert_eq!(default.youngs_modulus_pa, 3000.0);
        assert_eq!(tissues.len(), 2);
        assert_eq!(
            (tissues[1].label, tissues[1].material.youngs_modulus_pa),
            (2, 1895.0)
        );
        assert_eq!(scene.material.tissues[0].name, "grey matter");
        let err = Scene::parse(&with(&two.replace("label = 2", "label = 1")), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("material.tissue[1].label") && err.contains("material.tissue[0]"),
            "{err}"
        );
        let err = Scene::parse(&with(&two.replace("1895.0", "-1.0")), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("material.tissue[1].youngs_modulus_pa"),
            "{err}"
        );
        let bad_nu = two.replacen("poisson_ratio = 0.45", "poisson_ratio = 0.5", 1);
        let err = Scene::parse(&with(&bad_nu), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("material.tissue[0].poisson_ratio"), "{err}");
    }

    #[test]
    fn errors_name_the_field() {
        let (scene, _) = Scene::load("cube").unwrap();
        let text = include_str!("../../scenes/cube.toml");
        let bad = text.replace("poisson_ratio = 0.45", "poisson_ratio = 0.5");
        assert_ne!(bad, text);
        let err = Scene::parse(&bad, "x.toml").unwrap_err().to_string();
        assert!(
            err.contains("material.poisson_ratio") && err.contains("x.toml"),
            "{err}"
        );
        let bad = text.replace("thickness_m = ", "thickness_m = -");
        let err = Scene::parse(&bad, "x.toml").unwrap_err().to_string();
        assert!(err.contains("instrument[0].thickness_m"), "{err}");
        let bad = text.replace("[material]", "[material]\ncolour = 1");
        let err = Scene::parse(&bad, "x.toml").unwrap_err().to_string();
        assert!(err.contains("colour") && err.contains("line"), "{err}");
        assert!(matches!(
            Scene::load("no-such-scene"),
            Err(SceneError::Unknown { .. })
        ));
        assert_eq!(scene.name, "cube");
    }

    /// `collision.traversal` takes "bundled" (the default) or "per-ray";
    /// another value is refused naming the field's values.
    #[test]
    fn the_bvh_traversal_is_a_collision_setting() {
        let text = include_str!("../../scenes/cube.toml");
        let (scene, _) = Scene::load("cube").unwrap();
        assert_eq!(scene.collision.traversal, Traversal::Bundled);
        let per_ray = text.replace("[collision]", "[collision]\ntraversal = \"per-ray\"");
        assert_ne!(per_ray, text);
        let scene = Scene::parse(&per_ray, "x.toml").unwrap();
        assert_eq!(scene.collision.traversal, Traversal::PerRay);
        let bad = text.replace("[collision]", "[collision]\ntraversal = \"sideways\"");
        let err = Scene::parse(&bad, "x.toml").unwrap_err().to_string();
        assert!(
            err.contains("sideways") && err.contains("per-ray") && err.contains("bundled"),
            "{err}"
        );
    }

    /// `solver.element` takes "tet4" (the default) or
    /// "tet4-nodal-pressure"; the latter is refused with a nonlinear
    /// strategy, and an unknown value is refused naming the values.
    #[test]
    fn the_element_is_a_solver_setting_refused_where_the_strategy_cannot_build_it() {
        let text = include_str!("../../scenes/cube.toml");
        let (scene, _) = Scene::load("cube").unwrap();
        assert_eq!(scene.solver.element, Element::Tet4);
        let with = |strategy: &str, element: &str| {
            let t = text.replace(
                "[solver]\nstrategy = \"compliance\"",
                &format!("[solver]\nstrategy = \"{strategy}\"\nelement = \"{element}\""),
            );
            assert_ne!(t, text);
            Scene::parse(&t, "x.toml")
        };
        for strategy in ["compliance", "direct", "neo-hookean"] {
            let scene = with(strategy, "tet4-nodal-pressure").unwrap();
            assert_eq!(scene.solver.element, Element::Tet4NodalPressure);
        }
        // The corotational force is a rotated linear stress per element,
        // with no nodal part.
        let err = with("corotational", "tet4-nodal-pressure")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("solver.element") && err.contains("corotational"),
            "{err}"
        );
        let err = with("compliance", "tet10").unwrap_err().to_string();
        assert!(
            err.contains("tet10") && err.contains("tet4-nodal-pressure"),
            "{err}"
        );
    }

    /// The cube scene with a foundation of `k` Pa/m and `open` regions
    /// (TOML inline tables).
    fn cube_on_foundation(open: &str) -> String {
        format!(
            "{}\n[foundation]\nstiffness_pa_per_m = 1e6\nopen = [{open}]\n",
            include_str!("../../scenes/cube.toml")
        )
    }

    fn centroid(model: &crate::sim::core::engine::Model, f: &[u32; 3]) -> [f64; 3] {
        let mut c = [0.0; 3];
        for &n in f {
            let p = model.mesh.nodes[n as usize];
            for (ck, pk) in c.iter_mut().zip(p.iter()) {
                *ck += pk / 3.0;
            }
        }
        c
    }

    #[test]
    fn a_region_named_open_carries_no_springs() {
        // Open: the upper half of the cube (a box). No supported face has
        // its centroid there; the lower faces are all supported.
        let size = match Scene::load("cube").unwrap().0.model {
            ModelSpec::Cube { size_m, .. } => size_m,
            _ => unreachable!(),
        };
        let all = Scene::parse(&cube_on_foundation(""), "all.toml").unwrap();
        let all = crate::sim::core::engine::Model::build(&all).unwrap();
        let open = format!(
            "{{ box_min_m = [-1.0, -1.0, {}], box_max_m = [1.0, 1.0, 1.0] }}",
            size / 2.0
        );
        let half = Scene::parse(&cube_on_foundation(&open), "half.toml").unwrap();
        let half = crate::sim::core::engine::Model::build(&half).unwrap();
        let (fa, fh) = (
            all.foundation.as_ref().unwrap(),
            half.foundation.as_ref().unwrap(),
        );
        assert!(!fh.faces.is_empty() && fh.faces.len() < fa.faces.len());
        for f in &fh.faces {
            assert!(centroid(&half, f)[2] < size / 2.0, "{f:?} is open");
        }
        let below = fa
            .faces
            .iter()
            .filter(|f| centroid(&all, f)[2] < size / 2.0)
            .count();
        assert_eq!(below, fh.faces.len());
        // Faces of fixed nodes only (the cube's fixed bottom) carry none.
        for f in &fa.faces {
            assert!(!f.iter().all(|&n| all.fixed_mask[n as usize]), "{f:?}");
        }
        // A vertex list: the faces whose three nodes are listed are open.
        let dir = tempfile::tempdir().unwrap();
        let face = fa.faces[0];
        std::fs::write(
            dir.path().join("open.txt"),
            format!("# one face\n{}\n{}\n{}\n", face[0], face[1], face[2]),
        )
        .unwrap();
        let path = dir.path().join("listed.toml");
        std::fs::write(
            &path,
            cube_on_foundation("{ vertices_file = \"open.txt\" }"),
        )
        .unwrap();
        let (listed, _) = Scene::load(path.to_str().unwrap()).unwrap();
        let listed = crate::sim::core::engine::Model::build(&listed).unwrap();
        let fl = listed.foundation.as_ref().unwrap();
        assert_eq!(fl.faces.len(), fa.faces.len() - 1);
        assert!(!fl.faces.contains(&face));
    }

    #[test]
    fn an_unknown_region_is_named() {
        let scene = Scene::parse(
            &cube_on_foundation("{ landmark = \"craniotomy\" }"),
            "u.toml",
        )
        .unwrap();
        let err = crate::sim::core::engine::Model::build(&scene)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("craniotomy") && err.contains("foundation.open[0]"),
            "{err}"
        );
        let text = include_str!("../../scenes/sylvian.toml")
            .replace("preset = \"paper-48k\"", "preset = \"coarse\"")
            .replace(
                "landmark = \"sylvian-left\"",
                "landmark = \"sylvian-middle\"",
            );
        let scene = Scene::parse(&text, "s.toml").unwrap();
        let err = crate::sim::core::engine::Model::build(&scene)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("sylvian-middle") && err.contains("sylvian-left"),
            "{err}"
        );
        let err = Scene::parse(
            &cube_on_foundation("{ vertices_file = \"no-such-list.txt\" }"),
            "v.toml",
        )
        .map(|s| crate::sim::core::engine::Model::build(&s).map(|_| ()))
        .unwrap()
        .unwrap_err()
        .to_string();
        assert!(err.contains("no-such-list.txt"), "{err}");
        // The iterative strategies take a foundation too (their energy
        // holds its springs).
        for strategy in ["corotational", "neo-hookean"] {
            let text = cube_on_foundation("").replace(
                "strategy = \"compliance\"",
                &format!("strategy = \"{strategy}\""),
            );
            let scene = Scene::parse(&text, "c.toml").expect(strategy);
            assert!(scene.foundation.is_some());
        }
    }

    #[test]
    fn the_default_scenes_load_with_the_foundation() {
        // sylvian and interhemispheric are held by the foundation, open at
        // their window and their fissure; the coarse phantom stands in for
        // the 48k one here (the same landmarks).
        for (name, fissure) in [
            ("sylvian", "sylvian-left"),
            ("interhemispheric", "interhemispheric"),
        ] {
            let (scene, _) = Scene::load(name).unwrap();
            let f = scene.foundation.as_ref().expect(name);
            assert!(f.stiffness_pa_per_m > 0.0);
            assert!(
                f.open.iter().any(|r| *r
                    == Region::Landmark {
                        landmark: fissure.into()
                    }),
                "{name}"
            );
            let mut coarse = scene.clone();
            coarse.model = ModelSpec::Phantom {
                preset: "coarse".into(),
                proven: false,
                spacing_m: None,
                refine: 0,
                refine_near: Vec::new(),
            };
            let model = crate::sim::core::engine::Model::build(&coarse).unwrap();
            let springs = model.foundation.as_ref().unwrap();
            let total = model.surface.triangles.len();
            assert!(
                springs.faces.len() > total / 2 && springs.faces.len() < total,
                "{name}: {} of {total} faces supported",
                springs.faces.len()
            );
        }
        for name in ["cube", "v-valley", "u-valley"] {
            assert!(Scene::load(name).unwrap().0.foundation.is_none(), "{name}");
        }
    }
}
