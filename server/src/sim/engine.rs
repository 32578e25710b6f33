//! The engine a scene asks for, composed from the library stages: the model
//! (mesh, surface, instruments), the collision stage of each loop, and the
//! deformation stage (FEM solve, reactions, local force model).
//!
//! "Model only what a scene requires": the skull constraint exists only when
//! the scene names it; each instrument's rays are cast only for that
//! instrument; the force loop of an instrument queries that instrument alone.

use super::SimError;
use super::local_model::ForceModel;
use super::snapshot::{Frame, InstrumentReaction, Snapshot, StepTimings};
use crate::collide::brute::BruteForce;
use crate::collide::bvh::Bvh;
use crate::collide::contact::{self, ContactOutput, DetectOptions, Tool, Workspace};
use crate::collide::history::{HistoryMode as CollideHistoryMode, Stage};
use crate::collide::instrument::{Instrument, NodeLayout, Plate, RimNodes};
use crate::collide::{NodeHits, RayBackend, RayRange};
use crate::fem::{self, DeformationSolver, Prescribed};
use crate::mesh::{BoundarySurface, TetMesh};
use crate::scene::{
    CollisionBackend, CollisionMethod, HistoryMode, LayoutKind, ModelSpec, Region, Scene, ShapeKind,
};
use faer::Par;
use nalgebra::{DMatrix, Isometry3, Point3, Vector3};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

/// Contact history flags of one instrument.
pub type History = crate::collide::history::History;

/// The immutable model of a scene.
#[derive(Debug)]
pub struct Model {
    /// The tetrahedral mesh at rest, m.
    pub mesh: TetMesh,
    /// Its boundary surface.
    pub surface: BoundarySurface,
    /// Rest positions of the surface vertices, m.
    pub rest_surface: Vec<Point3<f64>>,
    /// Fixed volume nodes.
    pub fixed: Vec<u32>,
    /// The instruments, in scene order.
    pub instruments: Vec<Instrument>,
    history_mode: CollideHistoryMode,
}

fn build_instrument(
    spec: &crate::scene::InstrumentSpec,
    max_depth_m: f64,
) -> Result<Instrument, SimError> {
    let plate = match spec.shape {
        ShapeKind::Flat => Plate::flat(spec.thickness_m, spec.width_m, spec.length_m),
        ShapeKind::Trapezoid => Plate::trapezoid(
            spec.thickness_m,
            spec.base_width_m.unwrap_or(spec.width_m),
            spec.width_m,
            spec.length_m,
        ),
        ShapeKind::Curved => Plate::curved(
            spec.thickness_m,
            spec.width_m,
            spec.length_m,
            spec.bend_radius_m.unwrap_or(f64::INFINITY),
        ),
    };
    let per_face = spec.nodes_per_face as usize;
    let layout = match spec.layout {
        LayoutKind::WholeFace => NodeLayout::WholeFace { per_face },
        LayoutKind::Tip => NodeLayout::Tip {
            per_face,
            fraction: 0.3,
        },
    };
    let rim = spec.rim.then(|| RimNodes {
        per_side: ((spec.length_m / spec.width_m * 3.0).round() as usize).clamp(4, 64),
        tip: 5,
        tip_reach: spec.thickness_m.max(0.002),
    });
    let mut instrument = Instrument::new(plate, layout, rim)
        .map_err(|e| SimError::Model(format!("instrument {:?}: {e}", spec.name)))?;
    instrument.cap_reach(max_depth_m);
    Ok(instrument)
}

impl Model {
    /// Builds the mesh, the surface, the fixed set and the instruments.
    pub fn build(scene: &Scene) -> Result<Self, SimError> {
        let mut landmarks = None;
        let mesh = match &scene.model {
            ModelSpec::Cube { size_m, cells } => crate::mesh::blocks::cube(*size_m, *cells),
            ModelSpec::VValley => crate::mesh::blocks::v_valley(),
            ModelSpec::UValley => crate::mesh::blocks::u_valley(),
            ModelSpec::Phantom { preset, proven } => {
                let p = crate::mesh::phantom::preset_meshed(preset, *proven)
                    .map_err(|e| SimError::Model(e.to_string()))?;
                landmarks = Some(p.landmarks);
                p.mesh
            }
            ModelSpec::File { path, scale } => crate::mesh::io::read_model(path, *scale)
                .map_err(|e| SimError::Model(e.to_string()))?,
        };
        let mut regions = Vec::with_capacity(scene.fixed.len());
        for r in &scene.fixed {
            regions.push(match r {
                Region::Landmark { landmark } => match (landmark.as_str(), &landmarks) {
                    ("brain-stem", Some(l)) => Region::Sphere {
                        centre_m: l.brain_stem.centre.coords.into(),
                        radius_m: l.brain_stem.radius,
                    },
                    _ => {
                        return Err(SimError::Model(format!(
                            "the model has no landmark named {landmark:?} (the phantom has \"brain-stem\")"
                        )));
                    }
                },
                other => other.clone(),
            });
        }
        let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
            .filter(|&n| {
                let p = mesh.nodes[n as usize];
                regions.iter().any(|r| r.contains([p.x, p.y, p.z]))
            })
            .collect();
        let (mesh, fixed) = match &scene.roi {
            None => (mesh, fixed),
            Some(roi) => {
                let centre = nalgebra::Point3::from(roi.centre_m);
                let at = match roi.plane_normal {
                    None => fem::roi::RoiCentre::Point(centre),
                    Some(n) => fem::roi::RoiCentre::Plane {
                        point: centre,
                        normal: Vector3::from(n).normalize(),
                    },
                };
                let crop = fem::roi::crop(&mesh, at, roi.distance_m, &fixed)
                    .map_err(|e| SimError::Model(format!("region of interest: {e}")))?;
                tracing::info!(
                    tets = crop.mesh.tets.len(),
                    of = mesh.tets.len(),
                    cut_nodes = crop.cut_nodes.len(),
                    "region of interest cropped"
                );
                (crop.mesh, crop.fixed)
            }
        };
        if fixed.is_empty() {
            return Err(SimError::Model(
                "no node lies in the fixed region(s); the model would float".into(),
            ));
        }
        let surface = mesh.boundary();
        let mut rest_surface = Vec::new();
        surface.gather(&mesh.nodes, &mut rest_surface);
        let instruments = scene
            .instruments
            .iter()
            .map(|spec| build_instrument(spec, scene.collision.max_depth_m))
            .collect::<Result<_, _>>()?;
        let history_mode = match scene.collision.history {
            HistoryMode::ForceRate => CollideHistoryMode::ForceRate,
            HistoryMode::Paper => CollideHistoryMode::PaperFaithful,
        };
        Ok(Self {
            mesh,
            surface,
            rest_surface,
            fixed,
            instruments,
            history_mode,
        })
    }

    /// The collision stage's view of the surface at `positions` (m).
    pub fn contact_query<'a>(&'a self, positions: &'a [Point3<f64>]) -> contact::ContactQuery<'a> {
        contact::ContactQuery {
            positions,
            rest: &self.rest_surface,
            triangles: &self.surface.triangles,
            to_volume: &self.surface.to_volume,
        }
    }

    /// All flags off for instrument `i`.
    pub fn new_history(&self, i: usize) -> History {
        History::new(&self.instruments[i], self.history_mode)
    }

    /// Rim source nodes of instrument `i`.
    pub fn rim_node_count(&self, i: usize) -> usize {
        self.instruments[i].len() - 2 * self.instruments[i].per_face
    }

    /// Frame 0: the rest state, no contact.
    pub fn rest_snapshot(&self, scene: &Scene) -> Snapshot {
        let positions: Vec<[f32; 3]> = self
            .rest_surface
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let instruments = scene
            .instruments
            .iter()
            .map(|s| InstrumentReaction {
                name: s.name.clone(),
                force_n: Vector3::zeros(),
                torque_nm: Vector3::zeros(),
                pairs: 0,
                culled: 0,
                contact_vertices: 0,
                position_m: Vector3::from(s.home_position_m),
                orientation: s.home_orientation,
            })
            .collect();
        Snapshot {
            frame: 0,
            sim_time_s: 0.0,
            published: Instant::now(),
            surface: Arc::new(self.rest_surface.clone()),
            surface_bvh: None,
            force_model: Arc::new(ForceModel::default()),
            paper_history: (0..self.instruments.len())
                .map(|i| self.new_history(i))
                .collect(),
            solver_error: None,
            frame_summary: Arc::new(Frame {
                frame: 0,
                sim_time_s: 0.0,
                positions: Arc::new(positions),
                instruments,
                timings: StepTimings::default(),
                solver_error: None,
                max_displacement_m: 0.0,
            }),
        }
    }
}

/// Builds the ray backend a scene asks for over the given surface positions.
pub fn ray_backend(scene: &Scene, model: &Model, positions: &[Point3<f64>]) -> Box<dyn RayBackend> {
    let tris = &model.surface.triangles;
    let method = scene.collision.method;
    let cpu = move || -> Box<dyn RayBackend> {
        match method {
            CollisionMethod::Brute => {
                Box::new(BruteForce::new(tris, positions).expect("surface checked at load"))
            }
            CollisionMethod::Bvh => {
                Box::new(Bvh::new(tris, positions).expect("surface checked at load"))
            }
        }
    };
    match scene.collision.backend {
        CollisionBackend::Cpu => cpu(),
        CollisionBackend::Gpu => {
            let gpu_method = match method {
                CollisionMethod::Brute => crate::collide::gpu::GpuMethod::Brute,
                CollisionMethod::Bvh => crate::collide::gpu::GpuMethod::Bvh,
            };
            // Logs a warning with the reason when it falls back.
            let backend = crate::collide::gpu::backend_or_cpu(gpu_method, tris, positions, cpu);
            if backend.backend() == "gpu" {
                tracing::info!(
                    scene = %scene.name,
                    method = backend.method(),
                    "collision rays cast on the GPU"
                );
            } else {
                tracing::warn!(
                    scene = %scene.name,
                    method = backend.method(),
                    "scene asks for the GPU collision backend; falling back to the CPU backend"
                );
            }
            backend
        }
    }
}

/// The published surface BVHs of a scene with the CPU BVH: each step's tree
/// is refitted on the deformation thread, then shared read-only by the force
/// loops (and by the next step's collision) through the snapshot. The tree of
/// two steps ago is reused once nobody holds it (no allocation in steady
/// state); otherwise the current one is cloned.
#[derive(Debug)]
pub struct SurfaceBvhs {
    current: Arc<Bvh>,
    spare: Option<Arc<Bvh>>,
}

impl SurfaceBvhs {
    /// A tree over the rest surface, when the scene casts on the CPU BVH.
    pub fn new(scene: &Scene, model: &Model) -> Option<Self> {
        (scene.collision.method == CollisionMethod::Bvh
            && scene.collision.backend == CollisionBackend::Cpu)
            .then(|| Self {
                current: Arc::new(
                    Bvh::new(&model.surface.triangles, &model.rest_surface)
                        .expect("surface checked at load"),
                ),
                spare: None,
            })
    }

    /// The tree fitted to the rest surface (or whatever was published last).
    pub fn current(&self) -> Arc<Bvh> {
        self.current.clone()
    }

    /// A tree fitted to `surface`, to publish with it.
    pub fn fit(&mut self, surface: &[Point3<f64>]) -> Arc<Bvh> {
        let mut next = match self.spare.take().map(Arc::try_unwrap) {
            Some(Ok(tree)) => tree,
            _ => (*self.current).clone(),
        };
        next.update_positions(surface);
        let next = Arc::new(next);
        self.spare = Some(std::mem::replace(&mut self.current, next.clone()));
        next
    }
}

/// A published tree as a [`RayBackend`] of one query: casts read-only with the
/// caller's parallelism. Its positions are the snapshot's, fitted by the
/// deformation loop, so `update_positions` has nothing to do.
struct SharedBvh<'a> {
    tree: &'a Bvh,
    par: Par,
}

impl RayBackend for SharedBvh<'_> {
    fn method(&self) -> &'static str {
        "bvh"
    }

    fn backend(&self) -> &'static str {
        "cpu"
    }

    fn update_positions(&mut self, _positions: &[Point3<f64>]) {}

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        self.tree
            .cast_ranged_with(origins, dirs, &[], self.par, out);
    }

    fn cast_ranged(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        out: &mut Vec<NodeHits>,
    ) {
        self.tree
            .cast_ranged_with(origins, dirs, ranges, self.par, out);
    }
}

/// The collision stage of one loop: its own backend (fitted to the snapshot it
/// last saw) unless the snapshot carries a published tree, workspace and
/// output buffers. `par` is the parallelism of its casts on a published tree:
/// sequential for a force loop (on its own thread, never queued behind the
/// deformation loop's parallel work), the rayon pool for the deformation loop.
pub struct ContactQuery {
    scene: Scene,
    backend: Option<Box<dyn RayBackend>>,
    fitted: Option<Arc<Vec<Point3<f64>>>>,
    ws: Workspace,
    out: ContactOutput,
    opts: DetectOptions,
    by_node: EnforcedByNode,
    par: Par,
}

impl std::fmt::Debug for ContactQuery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContactQuery")
            .field("method", &self.backend.as_ref().map(|b| b.method()))
            .finish_non_exhaustive()
    }
}

/// A contact output's enforced displacements by volume node, for the local
/// force model's lookups (sorted; the buffer is reused).
#[derive(Debug, Clone, Default)]
pub struct EnforcedByNode(Vec<(u32, Vector3<f64>)>);

impl EnforcedByNode {
    /// Re-indexes `out`'s enforced displacements.
    pub fn rebuild(&mut self, out: &ContactOutput) {
        self.0.clear();
        self.0
            .extend(out.enforced.iter().map(|e| (e.volume_node, e.displacement)));
        self.0.sort_unstable_by_key(|e| e.0);
    }

    /// Enforced displacement of a volume node, if in contact.
    pub fn get(&self, node: u32) -> Option<Vector3<f64>> {
        self.0
            .binary_search_by_key(&node, |e| e.0)
            .ok()
            .map(|i| self.0[i].1)
    }

    /// Nodes with an enforced displacement.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// No node has an enforced displacement.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// The result of one query, borrowed from the query's buffers.
#[derive(Debug)]
pub struct ContactView<'a> {
    /// Pairs, cancelled pairs and enforced displacements.
    pub output: &'a ContactOutput,
    by_node: &'a EnforcedByNode,
}

impl ContactView<'_> {
    /// Enforced displacement of a volume node, if in contact.
    pub fn displacement_of(&self, node: u32) -> Option<Vector3<f64>> {
        self.by_node.get(node)
    }

    /// Surface vertices in contact.
    pub fn contact_count(&self) -> u32 {
        self.by_node.len() as u32
    }
}

impl ContactQuery {
    /// A collision stage for `scene` over the rest surface; casts on a
    /// published tree with parallelism `par`.
    pub fn new(scene: &Scene, par: Par) -> Self {
        Self {
            par,
            scene: scene.clone(),
            backend: None,
            fitted: None,
            ws: Workspace::new(),
            out: ContactOutput::default(),
            opts: DetectOptions {
                culling: scene.collision.culling,
                unilateral: scene.collision.unilateral,
                ..DetectOptions::default()
            },
            by_node: EnforcedByNode::default(),
        }
    }

    /// The backend to cast on for `snap`: its published tree, or this
    /// query's own backend fitted to its surface.
    /// Its own backend is built on first need (never, while snapshots carry
    /// a tree).
    fn backend_for<'a>(
        backend: &'a mut Option<Box<dyn RayBackend>>,
        fitted: &mut Option<Arc<Vec<Point3<f64>>>>,
        scene: &Scene,
        model: &Model,
        snap: &'a Snapshot,
        par: Par,
        shared: &'a mut Option<SharedBvh<'a>>,
    ) -> &'a mut dyn RayBackend {
        if let Some(tree) = &snap.surface_bvh {
            return shared.insert(SharedBvh { tree, par });
        }
        let backend = backend.get_or_insert_with(|| ray_backend(scene, model, &snap.surface));
        if !fitted
            .as_ref()
            .is_some_and(|f| Arc::ptr_eq(f, &snap.surface))
        {
            backend.update_positions(&snap.surface);
            *fitted = Some(snap.surface.clone());
        }
        backend.as_mut()
    }

    /// One instrument against the snapshot's surface (the force loop).
    pub fn query(
        &mut self,
        model: &Model,
        snap: &Snapshot,
        instrument: usize,
        pose: &Isometry3<f64>,
        history: &mut History,
    ) -> ContactView<'_> {
        let mut shared = None;
        let backend = Self::backend_for(
            &mut self.backend,
            &mut self.fitted,
            &self.scene,
            model,
            snap,
            Par::Seq,
            &mut shared,
        );
        let q = model.contact_query(&snap.surface);
        if let Err(e) = contact::detect(
            backend,
            &q,
            &model.instruments[instrument],
            pose,
            history,
            Stage::Force,
            &self.opts,
            &mut self.ws,
            &mut self.out,
        ) {
            tracing::warn!(error = %e, "collision query failed");
            self.out = ContactOutput::default();
        }
        self.by_node.rebuild(&self.out);
        ContactView {
            output: &self.out,
            by_node: &self.by_node,
        }
    }

    /// All instruments in one cast (the deformation loop).
    pub fn query_all(
        &mut self,
        model: &Model,
        snap: &Snapshot,
        poses: &[Isometry3<f64>],
        histories: &mut [History],
    ) -> &ContactOutput {
        let mut shared = None;
        let backend = Self::backend_for(
            &mut self.backend,
            &mut self.fitted,
            &self.scene,
            model,
            snap,
            self.par,
            &mut shared,
        );
        let q = model.contact_query(&snap.surface);
        let mut tools: Vec<Tool<'_>> = model
            .instruments
            .iter()
            .zip(poses)
            .zip(histories.iter_mut())
            .map(|((instrument, pose), history)| Tool {
                instrument,
                pose: *pose,
                history,
            })
            .collect();
        if let Err(e) = contact::detect_many(
            backend,
            &q,
            &mut tools,
            Stage::Deformation,
            &self.opts,
            &mut self.ws,
            &mut self.out,
        ) {
            tracing::warn!(error = %e, "collision query failed");
            self.out = ContactOutput::default();
        }
        &self.out
    }
}

/// The deformation stage: the FEM solver and the per-step bookkeeping.
pub struct Deformer {
    solver: Box<dyn DeformationSolver>,
    prescribed: Vec<Prescribed>,
    /// Enforced entry -> its index in `prescribed` (None: a fixed node).
    slot: Vec<Option<usize>>,
    /// Per volume node: fixed.
    fixed: Vec<bool>,
}

impl std::fmt::Debug for Deformer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deformer")
            .field("solver", &self.solver.name())
            .finish_non_exhaustive()
    }
}

/// What one successful step produced.
#[derive(Debug)]
pub struct StepResult {
    /// Displacement of every node, m.
    pub displacements: Vec<Vector3<f64>>,
    /// Reaction per prescribed node, N (order of the contact output's enforced list).
    pub reactions: Vec<Vector3<f64>>,
    /// The local force model.
    pub force_model: ForceModel,
}

impl Deformer {
    /// Builds (and factorizes) the solver the scene asks for.
    pub fn new(scene: &Scene, model: &Model) -> Result<Self, SimError> {
        let strategy = scene.solver.strategy;
        let material = fem::Material {
            youngs_modulus_pa: scene.material.youngs_modulus_pa,
            poisson_ratio: scene.material.poisson_ratio,
        };
        let mut options = fem::SolverOptions::default();
        options.iterative.tolerance = scene.solver.tolerance;
        options.iterative.max_outer = scene.solver.max_iterations;
        // The skull is modelled only when the scene names it.
        options.skull = scene.skull.as_ref().map(|skull| {
            let sphere = |s: &crate::scene::SphereSpec| fem::skull::Sphere {
                centre: nalgebra::Point3::from(s.centre_m),
                radius: s.radius_m,
            };
            fem::skull::Skull {
                containing: skull.containing.as_ref().map(sphere),
                excluding: skull.excluding.as_ref().map(sphere),
            }
        });
        let solver = fem::build_solver(strategy, &model.mesh, material, &model.fixed, &options)
            .map_err(|e| SimError::Solver(e.to_string()))?;
        Ok(Self {
            solver,
            prescribed: Vec::new(),
            slot: Vec::new(),
            fixed: {
                let mut mask = vec![false; model.mesh.nodes.len()];
                for &n in &model.fixed {
                    mask[n as usize] = true;
                }
                mask
            },
        })
    }

    /// Back to rest (an unconstrained solve gives zero displacement and resets
    /// warm starts).
    pub fn reset(&mut self) {
        let _ = self.solver.solve(&[]);
    }

    /// Solves with the contact output's enforced displacements.
    pub fn step(&mut self, contacts: &ContactOutput) -> Result<StepResult, fem::SolveError> {
        // A fixed node stays fixed: an enforced displacement there (a face
        // touching the supported region) is dropped and gets no reaction.
        self.prescribed.clear();
        self.slot.clear();
        for e in &contacts.enforced {
            if self
                .fixed
                .get(e.volume_node as usize)
                .copied()
                .unwrap_or(false)
            {
                self.slot.push(None);
            } else {
                self.slot.push(Some(self.prescribed.len()));
                self.prescribed.push(Prescribed {
                    node: e.volume_node,
                    displacement: e.displacement,
                });
            }
        }
        let solution = self.solver.solve(&self.prescribed)?;
        let displacements = solution.displacements.clone();
        let reactions: Vec<Vector3<f64>> = self
            .slot
            .iter()
            .map(|j| j.map_or_else(Vector3::zeros, |j| solution.reactions[j]))
            .collect();
        let force_model = match self.solver.local_model() {
            Some(local) => force_model_from(local, contacts, |n| n),
            None => held_force_model(contacts, &reactions),
        };
        Ok(StepResult {
            displacements,
            reactions,
            force_model,
        })
    }
}

/// For strategies without a local model (the iterative ones): the step's
/// contact set with its reactions and a zero stiffness, so the force loop holds
/// the step's reactions (a zero-order hold) until the next step, releasing the
/// nodes the instrument leaves.
fn held_force_model(contacts: &ContactOutput, reactions: &[Vector3<f64>]) -> ForceModel {
    let m = contacts.enforced.len();
    ForceModel::new(
        contacts.enforced.iter().map(|e| e.volume_node).collect(),
        contacts.enforced.iter().map(|e| e.instrument).collect(),
        contacts.enforced.iter().map(|e| e.displacement).collect(),
        reactions.to_vec(),
        &DMatrix::zeros(3 * m, 3 * m),
    )
}

/// The local force model of a step: the condensed stiffness `S = C^-1` of
/// the local model's contact nodes, with each node's owner (the instrument
/// that enforced it). `node_map` maps the solver's node indices to the
/// collision stage's (the identity unless the FEM runs on a cropped mesh).
/// `rest` is left empty and `frame` zero: the publisher fills them.
pub fn force_model_from(
    local: &fem::LocalModel,
    contacts: &ContactOutput,
    node_map: impl Fn(u32) -> u32,
) -> ForceModel {
    let owner_of: HashMap<u32, u16> = contacts
        .enforced
        .iter()
        .map(|e| (e.volume_node, e.instrument))
        .collect();
    let m = local.nodes.len();
    let stiffness = if m == 0 {
        DMatrix::zeros(0, 0)
    } else {
        match local.compliance.clone().cholesky() {
            Some(ch) => ch.inverse(),
            None => {
                tracing::warn!(
                    nodes = m,
                    "the compliance block is not positive definite; forces held at the step's values"
                );
                DMatrix::zeros(3 * m, 3 * m)
            }
        }
    };
    let nodes: Vec<u32> = local.nodes.iter().map(|&n| node_map(n)).collect();
    let owner = nodes
        .iter()
        .map(|n| owner_of.get(n).copied().unwrap_or(u16::MAX))
        .collect();
    ForceModel::new(
        nodes,
        owner,
        local.displacements.clone(),
        local.reactions.clone(),
        &stiffness,
    )
}

impl Model {
    /// Builds the snapshot of a successful step.
    pub(crate) fn snapshot_from(
        &self,
        scene: &Scene,
        frame: u64,
        sim_time_s: f64,
        step: StepResult,
        contacts: &ContactOutput,
        poses: &[Isometry3<f64>],
        paper_history: Vec<History>,
        timings: StepTimings,
    ) -> Snapshot {
        let mut surface = Vec::with_capacity(self.rest_surface.len());
        let mut max_d: f64 = 0.0;
        for (s, &v) in self.surface.to_volume.iter().enumerate() {
            let u = step.displacements[v as usize];
            max_d = max_d.max(u.norm());
            surface.push(self.rest_surface[s] + u);
        }
        let mut force_model = step.force_model;
        force_model.frame = frame;
        force_model.rest = force_model
            .nodes
            .iter()
            .map(|&n| self.mesh.nodes[n as usize])
            .collect();
        let instruments = scene
            .instruments
            .iter()
            .enumerate()
            .map(|(k, spec)| {
                let handle = poses[k].translation.vector;
                let mut force = Vector3::zeros();
                let mut torque = Vector3::zeros();
                let mut contact_vertices = 0;
                for (e, r) in contacts.enforced.iter().zip(&step.reactions) {
                    if e.instrument as usize == k {
                        let p = self.mesh.nodes[e.volume_node as usize].coords + e.displacement;
                        force -= r;
                        torque += (p - handle).cross(&(-r));
                        contact_vertices += 1;
                    }
                }
                let q = poses[k].rotation.quaternion();
                InstrumentReaction {
                    name: spec.name.clone(),
                    force_n: force,
                    torque_nm: torque,
                    pairs: contacts
                        .pairs
                        .iter()
                        .filter(|p| p.instrument as usize == k)
                        .count() as u32,
                    culled: contacts
                        .cancelled
                        .iter()
                        .filter(|p| p.instrument as usize == k)
                        .count() as u32,
                    contact_vertices,
                    position_m: handle,
                    orientation: [q.w, q.i, q.j, q.k],
                }
            })
            .collect();
        let positions = surface
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        Snapshot {
            frame,
            sim_time_s,
            published: Instant::now(),
            surface: Arc::new(surface),
            surface_bvh: None,
            force_model: Arc::new(force_model),
            paper_history,
            solver_error: None,
            frame_summary: Arc::new(Frame {
                frame,
                sim_time_s,
                positions: Arc::new(positions),
                instruments,
                timings,
                solver_error: None,
                max_displacement_m: max_d,
            }),
        }
    }
}
