//! The engine a scene asks for, composed from the library stages: the model
//! (mesh, surface, instruments), the collision stage of each loop, the
//! contact rows, and the deformation stage (the contact problem's solve,
//! the compliance patch the force loops solve on).
//!
//! "Model only what a scene requires": the skull's rows exist only when the
//! scene names it; each instrument's rays are cast only for that
//! instrument; the force loop of an instrument queries that instrument
//! alone.

use super::SimError;
use super::local_model::ForceModel;
use super::rows::{self, Anchors, FreePositions, Row, SKULL_OWNER};
use super::snapshot::{Frame, InstrumentReaction, Snapshot, StepTimings};
use crate::collide::RayBackend;
use crate::collide::brute::BruteForce;
use crate::collide::bvh::{Bvh, BvhView};
use crate::collide::contact::{self, ContactOutput, ContactRule, DetectOptions, Tool, Workspace};
use crate::collide::history::{HistoryMode as CollideHistoryMode, Stage};
use crate::collide::instrument::{Instrument, NodeLayout, Plate, RimNodes};
use crate::fem::compliance::ColumnPolicy;
use crate::fem::{self, CompliancePatch, ContactAnswer, ContactRow, DeformationSolver, RowKind};
use crate::mesh::{BoundarySurface, TetMesh};
use crate::scene::{
    CollisionBackend, CollisionMethod, ContactGeometry, ContactLaw, HistoryMode, LayoutKind,
    ModelSpec, Region, Scene, ShapeKind,
};
use faer::Par;
use nalgebra::{Isometry3, Point3, Vector3};
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
    /// Per volume node: fixed.
    pub fixed_mask: Vec<bool>,
    /// Per volume node: the stiffness of a contact answered before the
    /// node's compliance is computed, N/m (Young's modulus times the mean
    /// length of the node's surface edges: the order of a point load's
    /// stiffness on a half-space over one element; 0 inside).
    pub penalty_n_per_m: Vec<f64>,
    /// With a region of interest: each node's index in the uncropped model,
    /// and that model's node count.
    pub to_full: Option<(Vec<u32>, usize)>,
    /// Per volume node: its surface vertex, `u32::MAX` inside.
    pub from_volume: Vec<u32>,
    /// The elastic foundation's springs, when the scene has one.
    pub foundation: Option<fem::foundation::Foundation>,
    /// Per surface vertex, its neighbours on the surface.
    pub surface_neighbours: crate::mesh::adjacency::Csr,
    /// The rest surface the contact search runs on, when the scene's
    /// contact geometry is the rest shape ([`ContactGeometry::Rest`]).
    pub contact_rest: Option<RestContact>,
    history_mode: CollideHistoryMode,
}

/// The shape of a linearized contact search: the rest surface and, for
/// scenes that cast on the CPU BVH, its tree, built once and shared by the
/// deformation step and every force loop (no refit, ever).
#[derive(Debug)]
pub struct RestContact {
    /// Rest positions of the surface vertices, m.
    pub surface: Arc<Vec<Point3<f64>>>,
    /// A BVH over them (CPU BVH scenes).
    pub tree: Option<Arc<Bvh>>,
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
    let mut instrument =
        Instrument::new(plate, layout, rim).map_err(|source| SimError::Instrument {
            name: spec.name.clone(),
            source,
        })?;
    instrument.cap_reach(max_depth_m);
    Ok(instrument)
}

impl Model {
    /// Builds the mesh, the surface, the fixed set and the instruments.
    pub fn build(scene: &Scene) -> Result<Self, SimError> {
        scene.check_built(&scene.name)?;
        let mut landmarks = None;
        let mesh = match &scene.model {
            ModelSpec::Cube { size_m, cells } => crate::mesh::blocks::cube(*size_m, *cells),
            ModelSpec::VValley => crate::mesh::blocks::v_valley(),
            ModelSpec::UValley => crate::mesh::blocks::u_valley(),
            ModelSpec::Phantom { preset, proven } => {
                let p = crate::mesh::phantom::preset_meshed(preset, *proven)?;
                landmarks = Some(p.landmarks);
                p.mesh
            }
            ModelSpec::File { path, scale } => crate::mesh::io::read_model(path, *scale)?,
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
                        return Err(SimError::UnknownLandmark {
                            landmark: landmark.clone(),
                        });
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
        let (mesh, fixed, to_full) = match &scene.roi {
            None => (mesh, fixed, None),
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
                    .map_err(SimError::RegionOfInterest)?;
                tracing::info!(
                    tets = crop.mesh.tets.len(),
                    of = mesh.tets.len(),
                    cut_nodes = crop.cut_nodes.len(),
                    "region of interest cropped"
                );
                (
                    crop.mesh,
                    crop.fixed,
                    Some((crop.to_full, mesh.nodes.len())),
                )
            }
        };
        if fixed.is_empty() {
            return Err(SimError::Floating);
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
        let mut fixed_mask = vec![false; mesh.nodes.len()];
        for &n in &fixed {
            fixed_mask[n as usize] = true;
        }
        let mut edge_sum = vec![0.0; mesh.nodes.len()];
        let mut edge_count = vec![0u32; mesh.nodes.len()];
        for t in &surface.triangles {
            for a in 0..3 {
                let (i, j) = (t[a] as usize, t[(a + 1) % 3] as usize);
                let (vi, vj) = (surface.to_volume[i] as usize, surface.to_volume[j] as usize);
                let len = (mesh.nodes[vi] - mesh.nodes[vj]).norm();
                for v in [vi, vj] {
                    edge_sum[v] += len;
                    edge_count[v] += 1;
                }
            }
        }
        let e = scene.material.youngs_modulus_pa;
        let penalty_n_per_m = edge_sum
            .iter()
            .zip(&edge_count)
            .map(|(&s, &c)| if c > 0 { e * s / c as f64 } else { 0.0 })
            .collect();
        let foundation = scene
            .foundation
            .as_ref()
            .map(|f| {
                let to_full = to_full.as_ref().map(|t| t.0.as_slice());
                crate::scene::region::foundation(
                    f,
                    &mesh,
                    &surface,
                    &fixed_mask,
                    landmarks.as_ref(),
                    to_full,
                )
            })
            .transpose()?;
        let mut from_volume = vec![u32::MAX; mesh.nodes.len()];
        for (s, &v) in surface.to_volume.iter().enumerate() {
            from_volume[v as usize] = s as u32;
        }
        let contact_rest = (scene.contact_geometry() == ContactGeometry::Rest).then(|| {
            let tree = (scene.collision.method == CollisionMethod::Bvh
                && scene.collision.backend == CollisionBackend::Cpu)
                .then(|| {
                    Arc::new(
                        Bvh::new(&surface.triangles, &rest_surface).expect("surface checked above"),
                    )
                });
            RestContact {
                surface: Arc::new(rest_surface.clone()),
                tree,
            }
        });
        let surface_neighbours = crate::mesh::adjacency::surface_vertex_neighbours(
            &surface.triangles,
            rest_surface.len(),
        );
        Ok(Self {
            from_volume,
            surface_neighbours,
            contact_rest,
            mesh,
            surface,
            rest_surface,
            fixed,
            instruments,
            fixed_mask,
            penalty_n_per_m,
            to_full,
            foundation,
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
            solved: None,
        }
    }

    /// The surface (and its tree) a contact search at `snap` runs on: the
    /// rest shape for a linearized contact, else the snapshot's.
    pub fn contact_shape<'a>(
        &'a self,
        snap: &'a Snapshot,
    ) -> (&'a Arc<Vec<Point3<f64>>>, Option<&'a Arc<Bvh>>) {
        match &self.contact_rest {
            Some(r) => (&r.surface, r.tree.as_ref()),
            None => (&snap.surface, snap.surface_bvh.as_ref()),
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

    /// The rest state as frame `frame`, no contact.
    pub fn rest_snapshot(&self, scene: &Scene, frame: u64, sim_time_s: f64) -> Snapshot {
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
                pending_vertices: 0,
                position_m: Vector3::from(s.home_position_m),
                orientation: s.home_orientation,
            })
            .collect();
        Snapshot {
            frame,
            sim_time_s,
            published: Instant::now(),
            surface: Arc::new(self.rest_surface.clone()),
            displacements: Arc::new(vec![Vector3::zeros(); self.mesh.nodes.len()]),
            surface_bvh: None,
            force_model: Arc::new(ForceModel::new(
                frame,
                Arc::default(),
                Arc::default(),
                Vec::new(),
                Vec::new(),
                Anchors::default(),
                false,
                vec![(Vector3::zeros(), Vector3::zeros()); scene.instruments.len()],
            )),
            paper_history: (0..self.instruments.len())
                .map(|i| self.new_history(i))
                .collect(),
            solver_error: None,
            frame_summary: Arc::new(Frame {
                frame,
                sim_time_s,
                positions: Arc::new(positions),
                instruments,
                timings: StepTimings::default(),
                solver_error: None,
                max_displacement_m: 0.0,
                rigid: super::motion::RigidPart::default(),
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
        // Model::build refuses such scenes in a build without the `gpu`
        // feature (Scene::check_built); one changed after that runs on the CPU.
        #[cfg(not(feature = "gpu"))]
        CollisionBackend::Gpu => {
            tracing::warn!(
                scene = %scene.name,
                "scene asks for the GPU collision backend, which this build lacks (the `gpu` feature); casting on the CPU"
            );
            cpu()
        }
        #[cfg(feature = "gpu")]
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
    par: Par,
}

impl std::fmt::Debug for ContactQuery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContactQuery")
            .field("method", &self.backend.as_ref().map(|b| b.method()))
            .finish_non_exhaustive()
    }
}

/// The collision options a scene asks for.
pub fn detect_options(scene: &Scene) -> DetectOptions {
    DetectOptions {
        culling: scene.collision.culling,
        rule: match scene.contact.law {
            ContactLaw::Paper => ContactRule::Paper,
            ContactLaw::Frictionless | ContactLaw::Coulomb => ContactRule::Signorini,
        },
        band_m: scene.contact.band_m,
        ahead_m: scene.contact.ahead_m,
        cover_tolerance_m: scene.contact.cover_tolerance_m,
        facing_only: scene.contact_geometry() == ContactGeometry::Rest,
        ..DetectOptions::default()
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
            opts: detect_options(scene),
        }
    }

    /// A collision stage that casts on `backend` (kept fitted to the
    /// snapshots' surfaces), whatever the snapshots carry: e.g. a GPU
    /// backend the caller built.
    pub fn with_backend(scene: &Scene, backend: Box<dyn RayBackend>) -> Self {
        let mut q = Self::new(scene, Par::Seq);
        q.backend = Some(backend);
        q
    }

    /// The backend to cast on for `snap`: this query's own backend when it
    /// has one (fitted to the snapshot's surface), else the snapshot's
    /// published tree, else a backend of the scene's kind built now.
    #[allow(clippy::too_many_arguments)]
    fn backend_for<'a>(
        backend: &'a mut Option<Box<dyn RayBackend>>,
        fitted: &mut Option<Arc<Vec<Point3<f64>>>>,
        scene: &Scene,
        model: &Model,
        surface: &Arc<Vec<Point3<f64>>>,
        tree: Option<&'a Arc<Bvh>>,
        par: Par,
        shared: &'a mut Option<BvhView<'a>>,
    ) -> &'a mut dyn RayBackend {
        if backend.is_none() {
            if let Some(tree) = tree {
                return shared.insert(BvhView::new(tree, par));
            }
        }
        let backend = backend.get_or_insert_with(|| ray_backend(scene, model, surface));
        if !fitted.as_ref().is_some_and(|f| Arc::ptr_eq(f, surface)) {
            backend.update_positions(surface);
            *fitted = Some(surface.clone());
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
    ) -> &ContactOutput {
        let (surface, tree) = model.contact_shape(snap);
        let mut shared = None;
        let backend = Self::backend_for(
            &mut self.backend,
            &mut self.fitted,
            &self.scene,
            model,
            surface,
            tree,
            Par::Seq,
            &mut shared,
        );
        let mut q = model.contact_query(surface);
        if model.contact_rest.is_some() {
            q.solved = Some(&snap.surface);
        }
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
        // The one-instrument query numbers its tool 0: give the output the
        // scene's index.
        let k = instrument as u16;
        for p in self
            .out
            .pairs
            .iter_mut()
            .chain(self.out.cancelled.iter_mut())
        {
            p.instrument = k;
        }
        for e in &mut self.out.enforced {
            e.instrument = k;
        }
        for c in &mut self.out.candidates {
            c.instrument = k;
        }
        for e in &mut self.out.edges {
            e.instrument = k;
        }
        &self.out
    }

    /// All instruments in one cast (the deformation loop).
    pub fn query_all(
        &mut self,
        model: &Model,
        snap: &Snapshot,
        poses: &[Isometry3<f64>],
        histories: &mut [History],
    ) -> &ContactOutput {
        let (surface, tree) = model.contact_shape(snap);
        let solved = model.contact_rest.is_some().then_some(&snap.surface[..]);
        self.query_all_with(model, surface, tree, solved, poses, histories)
    }

    /// All instruments in one cast against `surface` (with its fitted
    /// tree, if any).
    pub fn query_all_on(
        &mut self,
        model: &Model,
        surface: &Arc<Vec<Point3<f64>>>,
        tree: Option<&Arc<Bvh>>,
        poses: &[Isometry3<f64>],
        histories: &mut [History],
    ) -> &ContactOutput {
        self.query_all_with(model, surface, tree, None, poses, histories)
    }

    /// [`Self::query_all_on`], with the last solve's surface (`solved`)
    /// when `surface` is another shape.
    fn query_all_with(
        &mut self,
        model: &Model,
        surface: &Arc<Vec<Point3<f64>>>,
        tree: Option<&Arc<Bvh>>,
        solved: Option<&[Point3<f64>]>,
        poses: &[Isometry3<f64>],
        histories: &mut [History],
    ) -> &ContactOutput {
        let mut shared = None;
        let backend = Self::backend_for(
            &mut self.backend,
            &mut self.fitted,
            &self.scene,
            model,
            surface,
            tree,
            self.par,
            &mut shared,
        );
        let mut q = model.contact_query(surface);
        q.solved = solved;
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

    /// The output of the last query.
    pub fn output(&self) -> &ContactOutput {
        &self.out
    }
}

/// How a scene's contact law makes rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowRule {
    /// The law.
    pub law: ContactLaw,
    /// The Coulomb coefficient (Coulomb only).
    pub friction: Option<f64>,
}

impl RowRule {
    /// The rule of `scene`.
    pub fn of(scene: &Scene) -> Self {
        Self {
            law: scene.contact.law,
            friction: match scene.contact.law {
                ContactLaw::Coulomb => scene.contact.friction_coefficient,
                _ => None,
            },
        }
    }

    /// The rows of a query's output for `owner`'s pose `pose_of(owner)`,
    /// with the free positions `free`, the last solve's displacements `now`
    /// (m; where a new frictional contact anchors) and the frictional
    /// anchors.
    #[allow(clippy::too_many_arguments)]
    pub fn rows(
        &self,
        model: &Model,
        out: &ContactOutput,
        free: &FreePositions<'_>,
        now: &[Vector3<f64>],
        anchors: &Anchors,
        poses: &[Isometry3<f64>],
        dst: &mut Vec<Row>,
    ) {
        match self.law {
            ContactLaw::Paper => {
                rows::from_enforced(&out.enforced, &model.mesh.nodes, &model.fixed_mask, dst)
            }
            _ => {
                let inputs = rows::RowInputs {
                    free: *free,
                    now,
                    friction: self.friction,
                    anchors,
                    poses,
                    fixed: &model.fixed_mask,
                };
                rows::from_candidates(&out.candidates, &inputs, dst);
                rows::from_edges(&out.edges, &inputs, dst);
            }
        }
    }
}

/// The skull spheres as contact rows (DESIGN.md section 3b's machinery):
/// each surface node within `band_m` of leaving the containing sphere (or
/// of entering the excluding one) at its current position `x` gets a
/// unilateral row along the radial direction `r = (x - c) / |x - c|`,
/// linearised there: the containing sphere pushes inward (`dir = -r`, gap
/// `R - r . (X + u - c)`), the excluding one outward (`dir = r`, gap
/// `r . (X + u - c) - R`).
#[derive(Debug, Clone)]
pub struct SkullRows {
    skull: fem::skull::Skull,
    band_m: f64,
}

impl SkullRows {
    /// The skull of `scene`, if it has one.
    pub fn of(scene: &Scene) -> Option<Self> {
        let skull = scene.skull.as_ref()?;
        let sphere = |s: &crate::scene::SphereSpec| fem::skull::Sphere {
            centre: Point3::from(s.centre_m),
            radius: s.radius_m,
        };
        Some(Self {
            skull: fem::skull::Skull {
                containing: skull.containing.as_ref().map(sphere),
                excluding: skull.excluding.as_ref().map(sphere),
            },
            band_m: scene.contact.band_m,
        })
    }

    /// Rows of the surface nodes within the band of a sphere at
    /// displacements `u` (and of every node in `also`), appended to `dst`.
    pub fn rows(&self, model: &Model, u: &[Vector3<f64>], also: &[u32], dst: &mut Vec<Row>) {
        let mut done = std::collections::HashSet::new();
        for &v in model.surface.to_volume.iter().chain(also) {
            if model.fixed_mask[v as usize] || !done.insert(v) {
                continue;
            }
            let rest = model.mesh.nodes[v as usize];
            let x = rest + u[v as usize];
            for (code, sphere, containing) in [
                (0u8, self.skull.containing, true),
                (1u8, self.skull.excluding, false),
            ] {
                let Some(s) = sphere else { continue };
                let d = x - s.centre;
                let dist = d.norm();
                let r = if dist > 0.0 { d / dist } else { Vector3::z() };
                let near = if containing {
                    dist > s.radius - self.band_m
                } else {
                    dist < s.radius + self.band_m
                };
                if !near && !also.contains(&v) {
                    continue;
                }
                let (dir, gap) = if containing {
                    (-r, s.radius - r.dot(&(rest - s.centre)))
                } else {
                    (r, r.dot(&(rest - s.centre)) - s.radius)
                };
                dst.push(Row {
                    key: rows::key(v, SKULL_OWNER, 7, code as u32),
                    owner: SKULL_OWNER,
                    row: ContactRow::at_node(v, dir, gap, RowKind::Unilateral),
                    point: s.centre + r * s.radius,
                    triangle: rows::NO_TRIANGLE,
                });
            }
        }
    }

    /// Surface nodes that violate a sphere at displacements `u` by more
    /// than `tol_m` and have no skull row in `have`.
    pub fn violations(
        &self,
        model: &Model,
        u: &[Vector3<f64>],
        have: &[Row],
        tol_m: f64,
        out: &mut Vec<u32>,
    ) {
        out.clear();
        let held: std::collections::HashSet<u32> = have
            .iter()
            .filter(|r| r.owner == SKULL_OWNER)
            .map(|r| r.row.node)
            .collect();
        for &v in &model.surface.to_volume {
            if model.fixed_mask[v as usize] || held.contains(&v) {
                continue;
            }
            let x = model.mesh.nodes[v as usize] + u[v as usize];
            let out_of = self
                .skull
                .containing
                .is_some_and(|s| (x - s.centre).norm() > s.radius + tol_m);
            let into = self
                .skull
                .excluding
                .is_some_and(|s| (x - s.centre).norm() < s.radius - tol_m);
            if out_of || into {
                out.push(v);
            }
        }
    }
}

/// The deformation stage: the FEM solver of the scene's strategy.
pub struct Deformer {
    solver: Box<dyn DeformationSolver>,
    answer: ContactAnswer,
    fem_rows: Vec<ContactRow>,
    patch: CompliancePatch,
}

impl std::fmt::Debug for Deformer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deformer")
            .field("solver", &self.solver.name())
            .finish_non_exhaustive()
    }
}

impl Deformer {
    /// Builds (and factorizes) the solver the scene asks for. `columns`
    /// says how a solve gets compliance columns it lacks (`hook` runs first
    /// on the background thread of [`ColumnPolicy::Defer`]).
    pub fn new(
        scene: &Scene,
        model: &Model,
        columns: ColumnPolicy,
        hook: Option<Arc<dyn Fn() + Send + Sync>>,
    ) -> Result<Self, SimError> {
        let strategy = scene.solver.strategy;
        let material = fem::Material {
            youngs_modulus_pa: scene.material.youngs_modulus_pa,
            poisson_ratio: scene.material.poisson_ratio,
        };
        let mut options = fem::SolverOptions::default();
        options.iterative.tolerance = scene.solver.tolerance;
        options.iterative.max_outer = scene.solver.max_iterations;
        options.foundation = model.foundation.clone();
        let mut solver = fem::build_solver(strategy, &model.mesh, material, &model.fixed, &options)
            .map_err(SimError::Solver)?;
        solver.set_column_policy(columns, hook);
        Ok(Self {
            solver,
            answer: ContactAnswer::default(),
            fem_rows: Vec::new(),
            patch: CompliancePatch::default(),
        })
    }

    /// The strategy's name.
    pub fn strategy(&self) -> &'static str {
        self.solver.name()
    }

    /// Back to rest (an unconstrained solve gives zero displacement and resets
    /// warm starts).
    pub fn reset(&mut self) {
        let _ = self.solver.solve(&[]);
        self.answer = ContactAnswer::default();
    }

    /// Solves the contact problem of `rows`, warm-started from `warm` (one
    /// multiplier per row, or empty). On success the multipliers are in
    /// [`Self::answer`] and the displacements in [`Self::displacements`].
    pub fn solve(&mut self, rows: &[Row], warm: &[f64]) -> Result<(), fem::SolveError> {
        self.fem_rows.clear();
        self.fem_rows.extend(rows.iter().map(|r| r.row));
        self.answer.multipliers.clear();
        if warm.len() == rows.len() {
            self.answer.multipliers.extend_from_slice(warm);
        }
        self.solver.solve_contact(&self.fem_rows, &mut self.answer)
    }

    /// The last contact solve's answer.
    pub fn answer(&self) -> &ContactAnswer {
        &self.answer
    }

    /// Every node's displacement after the last successful solve, m.
    pub fn displacements(&self) -> &[Vector3<f64>] {
        self.solver
            .last_solution()
            .map(|s| s.displacements.as_slice())
            .unwrap_or(&[])
    }

    /// Solver iterations of the last solve.
    pub fn iterations(&self) -> u32 {
        self.solver.last_solution().map_or(0, |s| s.iterations)
    }

    /// The compliance patch over `nodes`, if the strategy has one.
    pub fn patch(&mut self, nodes: &[u32]) -> Option<CompliancePatch> {
        if self.solver.compliance_patch(nodes, &mut self.patch) {
            Some(std::mem::take(&mut self.patch))
        } else {
            None
        }
    }

    /// Asks for the compliance of `nodes` ahead of contact.
    pub fn prefetch(&mut self, nodes: &[u32]) {
        self.solver.prefetch(nodes);
    }
}

/// The penalty answer of a row whose node has no compliance yet
/// (flagged): `lambda = k max(0, -g)` for a unilateral row (`-k g` for a
/// bilateral one) at the gap `g = g_free + d . u` of the displacements `u`
/// the tissue has now, with the node's penalty stiffness `k`.
pub fn penalty(model: &Model, row: &Row, u: &[Vector3<f64>]) -> f64 {
    let k = row
        .row
        .nodes()
        .map(|(n, _)| model.penalty_n_per_m[n as usize])
        .fold(0.0, f64::max);
    let g = row.row.gap_free_m + row.row.normal_motion(u);
    match row.row.kind {
        RowKind::Unilateral => k * (-g).max(0.0),
        RowKind::Bilateral => -k * g,
        _ => 0.0,
    }
}

/// What one deformation step did, beyond the snapshot it publishes.
#[derive(Debug, Clone, Default)]
pub struct StepReport {
    /// Rows of the contact problem.
    pub rows: usize,
    /// Rows answered by a penalty (their compliance is not computed yet).
    pub pending: usize,
    /// Solver iterations.
    pub iterations: u32,
    /// Skull rounds (solves) of the step.
    pub rounds: u32,
    /// The contact solver's check of its answer.
    pub check: fem::lcp::Report,
    /// Nodes of the published compliance patch.
    pub patch_nodes: usize,
}

/// The deformation step of a scene: collision of every instrument, the
/// contact rows, the solve, and the snapshot the force loops read. Used by
/// the free-running deformation thread and by the stepped runner alike.
pub struct StepEngine {
    scene: Scene,
    model: Arc<Model>,
    deformer: Deformer,
    query: ContactQuery,
    /// The contact search's own collision stage (its own backend, fitted
    /// to each solved shape).
    search: ContactQuery,
    bvhs: Option<SurfaceBvhs>,
    paper_history: Vec<History>,
    anchors: Anchors,
    rule: RowRule,
    skull: Option<SkullRows>,
    next_frame: u64,
    rows: Vec<Row>,
    warm: Vec<f64>,
    extra: Vec<u32>,
    lambda: Vec<f64>,
}

impl std::fmt::Debug for StepEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepEngine")
            .field("scene", &self.scene.name)
            .field("next_frame", &self.next_frame)
            .finish_non_exhaustive()
    }
}

/// Most solves of one step while the skull finds new nodes leaving it.
const SKULL_ROUNDS: u32 = 8;

/// Most contact searches on a step's solved shape (rounds of the contact
/// geometry's fixed point).
const CONTACT_SEARCHES: u32 = 8;

/// The contact geometry has converged when a search on the solved shape
/// finds the problem's rows with point weights (barycentric, 1) within
/// this of the problem's.
const GEOMETRY_TOLERANCE: f64 = 1e-6;

impl StepEngine {
    /// The step of `scene` over `model` (factorizes the solver). `columns`
    /// and `hook` as in [`Deformer::new`]; `query` casts on the scene's
    /// backend unless the caller gives one.
    pub fn new(
        scene: &Scene,
        model: Arc<Model>,
        columns: ColumnPolicy,
        hook: Option<Arc<dyn Fn() + Send + Sync>>,
        backend: Option<Box<dyn RayBackend>>,
    ) -> Result<Self, SimError> {
        let deformer = Deformer::new(scene, &model, columns, hook)?;
        let query = match backend {
            Some(b) => ContactQuery::with_backend(scene, b),
            None => ContactQuery::new(scene, Par::rayon(0)),
        };
        // The search casts on a CPU tree of its own (every backend gives the
        // same answers).
        let search = ContactQuery::with_backend(
            scene,
            Box::new(
                Bvh::new(&model.surface.triangles, &model.rest_surface)
                    .expect("surface checked at load"),
            ),
        );
        // A linearized contact searches the model's rest tree: no tree is
        // published, nor refitted.
        let bvhs = if model.contact_rest.is_none() {
            SurfaceBvhs::new(scene, &model)
        } else {
            None
        };
        let paper_history = (0..model.instruments.len())
            .map(|i| model.new_history(i))
            .collect();
        Ok(Self {
            scene: scene.clone(),
            deformer,
            query,
            search,
            bvhs,
            paper_history,
            anchors: Anchors::default(),
            rule: RowRule::of(scene),
            skull: SkullRows::of(scene),
            next_frame: 0,
            rows: Vec::new(),
            warm: Vec::new(),
            extra: Vec::new(),
            lambda: Vec::new(),
            model,
        })
    }

    /// The model.
    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// The solver strategy's name.
    pub fn strategy(&self) -> &'static str {
        self.deformer.strategy()
    }

    /// The rest state as the next frame (at `sim_time_s`), with the
    /// histories, anchors and solver back to rest.
    pub fn rest(&mut self, sim_time_s: f64) -> Snapshot {
        self.deformer.reset();
        for (i, h) in self.paper_history.iter_mut().enumerate() {
            *h = self.model.new_history(i);
        }
        self.anchors = Anchors::default();
        let frame = self.next_frame;
        self.next_frame += 1;
        let mut snap = self.model.rest_snapshot(&self.scene, frame, sim_time_s);
        snap.surface_bvh = self.bvhs.as_mut().map(|b| b.fit(&snap.surface));
        // A strategy with a compliance operator answers contacts before the
        // first step too (with penalties until its columns exist).
        if self.deformer.patch(&[]).is_some() {
            if let Some(fm) = Arc::get_mut(&mut snap.force_model) {
                fm.has_patch = true;
            }
        }
        snap
    }

    /// One deformation step at `sim_time_s` from `prev`: instrument `i` at
    /// `poses[i]` with the force loop's history `histories[i]` (force-rate
    /// mode; `None`: an instrument at home, or the paper's mode, uses the
    /// step's own history).
    pub fn step(
        &mut self,
        prev: &Snapshot,
        sim_time_s: f64,
        poses: &[Isometry3<f64>],
        histories: Vec<Option<History>>,
    ) -> (Snapshot, Option<StepReport>) {
        let started = Instant::now();
        let model = self.model.clone();
        let frame = self.next_frame;
        self.next_frame += 1;
        let paper_mode = self.scene.collision.history == HistoryMode::Paper;
        let own: Vec<bool> = histories
            .iter()
            .map(|h| paper_mode || h.is_none())
            .collect();
        let mut step_histories: Vec<History> = histories
            .into_iter()
            .enumerate()
            .map(|(i, h)| match h {
                Some(h) if !paper_mode => h,
                _ => self.paper_history[i].clone(),
            })
            .collect();
        let t0 = Instant::now();
        let contacts = tracing::debug_span!("collision").in_scope(|| {
            self.query
                .query_all(&model, prev, poses, &mut step_histories)
        });
        let mut after = step_histories.clone();
        for (i, h) in step_histories.into_iter().enumerate() {
            if own[i] {
                self.paper_history[i] = h;
            }
        }
        let collision_us = t0.elapsed().as_secs_f64() * 1e6;
        let t1 = Instant::now();
        // Rows: the instruments', then the skull's.
        self.rows.clear();
        self.rule.rows(
            &model,
            contacts,
            &FreePositions::Rest(&model.mesh.nodes),
            &prev.displacements,
            &self.anchors,
            poses,
            &mut self.rows,
        );
        let last = prev.force_model.clone();
        let mut n_instrument_rows = self.rows.len();
        // What the snapshot needs of the collision output.
        let counts: Vec<(u32, u32)> = (0..model.instruments.len())
            .map(|k| {
                let pairs = contacts.pairs_of(k as u16).count() as u32;
                let culled = contacts
                    .cancelled
                    .iter()
                    .filter(|p| p.instrument as usize == k)
                    .count() as u32;
                (pairs, culled)
            })
            .collect();
        let nearby = contacts.nearby.clone();
        if let Some(skull) = &self.skull {
            skull.rows(&model, &prev.displacements, &[], &mut self.rows);
        }
        // Warm start from the last step's multipliers, by key.
        self.warm.clear();
        self.warm.extend(
            self.rows
                .iter()
                .map(|r| last.step_multiplier(r.key).unwrap_or(0.0)),
        );
        let mut rounds = 0;
        let mut searches = 0;
        let result = loop {
            rounds += 1;
            if let Err(e) = self.deformer.solve(&self.rows, &self.warm) {
                break Err(e);
            }
            // Skull nodes leaving the sphere join the problem.
            if let Some(skull) = &self.skull {
                let u = self.deformer.displacements();
                skull.violations(
                    &model,
                    u,
                    &self.rows,
                    1e-9 * skull.band_m.max(1e-6),
                    &mut self.extra,
                );
                if !self.extra.is_empty() && rounds < SKULL_ROUNDS {
                    let extra = std::mem::take(&mut self.extra);
                    let u = self.deformer.displacements().to_vec();
                    skull.rows(&model, &u, &extra, &mut self.rows);
                    self.extra = extra;
                    self.warm = self.deformer.answer().multipliers.clone();
                    self.warm.resize(self.rows.len(), 0.0);
                    continue;
                }
            }
            // Contact search on the solved shape: rows a query at the
            // step's poses finds there that the solution violates (tissue
            // the plate now pierces elsewhere) join the problem.
            // (None for a linearized contact: its rows do not depend on
            // the shape.)
            if model.contact_rest.is_none() && searches < CONTACT_SEARCHES {
                searches += 1;
                if self.search_solved(&model, poses, &after, &mut n_instrument_rows) {
                    continue;
                }
            }
            break Ok(());
        };
        let solve_us = t1.elapsed().as_secs_f64() * 1e6;
        let timings = |total: f64| StepTimings {
            collision_us,
            solve_us,
            total_us: total,
        };
        if let Err(e) = result {
            tracing::warn!(frame, error = %e, "deformation step failed; keeping the last good state");
            let mut summary = (*prev.frame_summary).clone();
            summary.frame = frame;
            summary.sim_time_s = sim_time_s;
            summary.timings = timings(started.elapsed().as_secs_f64() * 1e6);
            summary.solver_error = Some(e.to_string());
            let mut fm = (*prev.force_model).clone();
            fm.frame = frame;
            return (
                Snapshot {
                    frame,
                    sim_time_s,
                    published: Instant::now(),
                    surface: prev.surface.clone(),
                    displacements: prev.displacements.clone(),
                    surface_bvh: prev.surface_bvh.clone(),
                    force_model: Arc::new(fm),
                    paper_history: prev.paper_history.clone(),
                    solver_error: Some(e.to_string()),
                    frame_summary: Arc::new(summary),
                },
                None,
            );
        }
        let answer = self.deformer.answer();
        self.lambda.clear();
        self.lambda.extend_from_slice(&answer.multipliers);
        for (k, h) in self.paper_history.iter_mut().enumerate() {
            if own[k] {
                h.set_seeds(rows::seeds_of(
                    &self.rows,
                    &self.lambda,
                    k as u16,
                    &model.surface.triangles,
                    &model.from_volume,
                ));
            }
        }
        // Rows whose node has no compliance yet: a penalty at the tissue's
        // present shape.
        for &p in &answer.pending {
            self.lambda[p as usize] = penalty(&model, &self.rows[p as usize], &prev.displacements);
        }
        let pending = answer.pending.clone();
        let check = answer.report;
        let iterations = self.deformer.iterations();
        let displacements = Arc::new(self.deformer.displacements().to_vec());
        if self.rule.friction.is_some() {
            self.update_anchors(&model, poses, &displacements, n_instrument_rows);
        }
        // The new surface and its tree; the force loops query it, so the
        // patch covers the rows a query at the step's poses finds on it too.
        let mut surface = Vec::with_capacity(model.rest_surface.len());
        for (s, &v) in model.surface.to_volume.iter().enumerate() {
            surface.push(model.rest_surface[s] + displacements[v as usize]);
        }
        let surface = Arc::new(surface);
        let surface_bvh =
            tracing::debug_span!("refit").in_scope(|| self.bvhs.as_mut().map(|b| b.fit(&surface)));
        let mut patch_nodes: Vec<u32> = self
            .rows
            .iter()
            .flat_map(|r| r.row.nodes().map(|(n, _)| n))
            .collect();
        let mut ahead = Vec::new();
        let band2 = 2.0 * self.scene.contact.band_m;
        for n in &nearby {
            if n.distance_m <= band2 {
                patch_nodes.push(n.volume_node);
            } else {
                ahead.push(n.volume_node);
            }
        }
        // (A linearized contact finds the same rows on any shape.)
        if model.contact_rest.is_none() {
            let post =
                self.query
                    .query_all_on(&model, &surface, surface_bvh.as_ref(), poses, &mut after);
            let mut post_rows = Vec::new();
            self.rule.rows(
                &model,
                post,
                &FreePositions::Rest(&model.mesh.nodes),
                &prev.displacements,
                &self.anchors,
                poses,
                &mut post_rows,
            );
            patch_nodes.extend(post_rows.iter().flat_map(|r| r.row.nodes().map(|(n, _)| n)));
            for n in &post.nearby {
                if n.distance_m <= band2 {
                    patch_nodes.push(n.volume_node);
                } else {
                    ahead.push(n.volume_node);
                }
            }
        }
        // And one ring of surface neighbours: a plate's outline that moves
        // within the interval crosses triangles beyond the vertices the
        // step found, and a polygon point there names all three.
        patch_nodes.sort_unstable();
        patch_nodes.dedup();
        let found = patch_nodes.len();
        for i in 0..found {
            let s = model.from_volume[patch_nodes[i] as usize];
            if s != u32::MAX {
                patch_nodes.extend(
                    model
                        .surface_neighbours
                        .row(s as usize)
                        .iter()
                        .map(|&w| model.surface.to_volume[w as usize]),
                );
            }
        }
        patch_nodes.sort_unstable();
        patch_nodes.dedup();
        patch_nodes.retain(|&v| !model.fixed_mask[v as usize]);
        let patch = self.deformer.patch(&patch_nodes);
        ahead.sort_unstable();
        ahead.dedup();
        ahead.retain(|&v| !model.fixed_mask[v as usize]);
        self.deformer.prefetch(&ahead);
        let has_patch = patch.is_some();
        let patch = Arc::new(patch.unwrap_or_default());
        let mut patch_index = vec![u32::MAX; model.mesh.nodes.len()];
        for (i, &v) in patch.nodes.iter().enumerate() {
            patch_index[v as usize] = i as u32;
        }
        let report = StepReport {
            rows: self.rows.len(),
            pending: pending.len(),
            iterations,
            rounds,
            check,
            patch_nodes: patch.nodes.len(),
        };
        let total_us = started.elapsed().as_secs_f64() * 1e6;
        let snap = self.snapshot(
            frame,
            sim_time_s,
            &counts,
            poses,
            surface,
            surface_bvh,
            displacements,
            ForcePatch {
                patch,
                patch_index: Arc::new(patch_index),
                has_patch,
            },
            &pending,
            timings(total_us),
        );
        (snap, Some(report))
    }

    /// The contact geometry's fixed point, one round of [`Self::step`]:
    /// queries the solved shape at `poses` (with copies of the histories
    /// after the step's query) and, unless its instrument rows are the
    /// problem's (same keys, point weights within
    /// [`GEOMETRY_TOLERANCE`]), makes them the problem's, each point row
    /// half-way to the problem's row of its key ([`rows::midway`]: a
    /// corner's tissue point moves with the shape it pushes, and the plain
    /// iteration can swing between two shapes); the skull's rows follow.
    /// Returns whether the rows changed; `n_instrument_rows` counts the
    /// instrument rows at the front.
    fn search_solved(
        &mut self,
        model: &Model,
        poses: &[Isometry3<f64>],
        histories: &[History],
        n_instrument_rows: &mut usize,
    ) -> bool {
        let u = self.deformer.displacements();
        let surface: Vec<Point3<f64>> = model
            .surface
            .to_volume
            .iter()
            .enumerate()
            .map(|(s, &v)| model.rest_surface[s] + u[v as usize])
            .collect();
        let surface = Arc::new(surface);
        let mut h = histories.to_vec();
        let multipliers = &self.deformer.answer().multipliers;
        for (k, hk) in h.iter_mut().enumerate() {
            hk.set_seeds(rows::seeds_of(
                &self.rows,
                multipliers,
                k as u16,
                &model.surface.triangles,
                &model.from_volume,
            ));
        }
        let found = self
            .search
            .query_all_on(model, &surface, None, poses, &mut h);
        let free = FreePositions::Rest(&model.mesh.nodes);
        let mut post = Vec::new();
        self.rule
            .rows(model, found, &free, u, &self.anchors, poses, &mut post);
        let old = &self.rows[..*n_instrument_rows];
        let by_key: std::collections::HashMap<u64, usize> =
            old.iter().enumerate().map(|(i, r)| (r.key, i)).collect();
        let mut same = post.len() == old.len();
        for r in post.iter_mut() {
            match by_key.get(&r.key) {
                Some(&i) => {
                    let o = &old[i];
                    if r.row.is_point() || o.row.is_point() {
                        let dw = (0..3)
                            .map(|k| (r.triangle.1[k] - o.triangle.1[k]).abs())
                            .fold(0.0, f64::max);
                        if dw > GEOMETRY_TOLERANCE {
                            same = false;
                            *r = rows::midway(o, r, &free, &model.fixed_mask);
                        }
                    }
                }
                None => same = false,
            }
        }
        if same {
            return false;
        }
        let multipliers = &self.deformer.answer().multipliers;
        let old_lambda: std::collections::HashMap<u64, f64> = self
            .rows
            .iter()
            .zip(multipliers)
            .map(|(r, &l)| (r.key, l))
            .collect();
        let skull: Vec<Row> = self.rows[*n_instrument_rows..].to_vec();
        self.rows.clear();
        rows::append(&mut self.rows, &post);
        *n_instrument_rows = self.rows.len();
        rows::append(&mut self.rows, &skull);
        self.warm.clear();
        self.warm.extend(
            self.rows
                .iter()
                .map(|r| old_lambda.get(&r.key).copied().unwrap_or(0.0)),
        );
        true
    }

    /// Friction: a contact that slipped sticks where it ended; one that
    /// stuck keeps its anchor (a new one anchors where it touched); an
    /// open one forgets its anchor.
    fn update_anchors(
        &mut self,
        model: &Model,
        poses: &[Isometry3<f64>],
        u: &[Vector3<f64>],
        n_instrument_rows: usize,
    ) {
        let mut keep = std::collections::HashSet::new();
        let rows = &self.rows[..n_instrument_rows];
        for (i, r) in rows.iter().enumerate() {
            if r.row.kind != RowKind::Unilateral || self.lambda[i] <= 0.0 {
                continue;
            }
            let Some(pose) = poses.get(r.owner as usize) else {
                continue;
            };
            let mu = self.rule.friction.unwrap_or(0.0);
            let lt: f64 = rows
                .iter()
                .zip(&self.lambda)
                .filter(|(t, _)| matches!(t.row.kind, RowKind::Tangent { normal, .. } if normal as usize == i))
                .map(|(_, l)| l * l)
                .sum::<f64>()
                .sqrt();
            let slipping = lt >= mu * self.lambda[i] * (1.0 - 1e-6);
            keep.insert(r.key);
            if slipping || self.anchors.get(r.key).is_none() {
                // Where the tissue point is now, on the face plane: a
                // vertex, or a point row's own point of its triangle.
                let (nodes, weights) = if rows::is_point_key(r.key) {
                    r.triangle
                } else {
                    ([r.row.node, u32::MAX, u32::MAX], [1.0, 0.0, 0.0])
                };
                let x = rows::tissue_point(&model.mesh.nodes, u, &nodes, &weights);
                let on_face = x - r.row.dir * r.row.dir.dot(&(x - r.point));
                self.anchors.set(
                    r.key,
                    rows::Anchor {
                        at: pose.inverse() * on_face,
                        weights,
                    },
                );
            }
        }
        self.anchors.retain(|k| keep.contains(&k));
        self.anchors.set_poses(poses);
    }

    #[allow(clippy::too_many_arguments)]
    fn snapshot(
        &mut self,
        frame: u64,
        sim_time_s: f64,
        counts: &[(u32, u32)],
        poses: &[Isometry3<f64>],
        surface: Arc<Vec<Point3<f64>>>,
        surface_bvh: Option<Arc<Bvh>>,
        displacements: Arc<Vec<Vector3<f64>>>,
        patch: ForcePatch,
        pending: &[u32],
        timings: StepTimings,
    ) -> Snapshot {
        let model = &self.model;
        let max_d = model
            .surface
            .to_volume
            .iter()
            .map(|&v| displacements[v as usize].norm())
            .fold(0.0, f64::max);
        let mut step_force = Vec::with_capacity(self.scene.instruments.len());
        let instruments = self
            .scene
            .instruments
            .iter()
            .enumerate()
            .map(|(k, spec)| {
                let handle = poses[k].translation.vector;
                let (force, torque) =
                    rows::owner_force(&self.rows, &self.lambda, k as u16, &handle);
                step_force.push((force, torque));
                let mut touching: Vec<u32> = self
                    .rows
                    .iter()
                    .zip(&self.lambda)
                    .filter(|(r, l)| r.owner as usize == k && **l != 0.0)
                    .map(|(r, _)| r.row.node)
                    .collect();
                touching.sort_unstable();
                touching.dedup();
                let mut waiting: Vec<u32> = pending
                    .iter()
                    .map(|&p| &self.rows[p as usize])
                    .filter(|r| r.owner as usize == k)
                    .map(|r| r.row.node)
                    .collect();
                waiting.sort_unstable();
                waiting.dedup();
                let q = poses[k].rotation.quaternion();
                InstrumentReaction {
                    name: spec.name.clone(),
                    force_n: force,
                    torque_nm: torque,
                    pairs: counts[k].0,
                    culled: counts[k].1,
                    contact_vertices: touching.len() as u32,
                    pending_vertices: waiting.len() as u32,
                    position_m: handle,
                    orientation: [q.w, q.i, q.j, q.k],
                }
            })
            .collect();
        let rigid = super::motion::RigidPart::of(
            &model.rest_surface,
            &surface,
            tips_centre(&self.scene, poses),
        );
        let positions = surface
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let force_model = ForceModel::new(
            frame,
            patch.patch,
            patch.patch_index,
            self.rows.clone(),
            self.lambda.clone(),
            self.anchors.clone(),
            patch.has_patch,
            step_force,
        );
        Snapshot {
            frame,
            sim_time_s,
            published: Instant::now(),
            surface,
            displacements,
            surface_bvh,
            force_model: Arc::new(force_model),
            paper_history: self.paper_history.clone(),
            solver_error: None,
            frame_summary: Arc::new(Frame {
                frame,
                sim_time_s,
                positions: Arc::new(positions),
                instruments,
                timings,
                solver_error: None,
                max_displacement_m: max_d,
                rigid,
            }),
        }
    }
}

/// The mean of the instruments' tips (`+z` of the plate frame at its
/// length from the handle), m: the fissure's centre while they work in it.
fn tips_centre(scene: &Scene, poses: &[Isometry3<f64>]) -> Point3<f64> {
    let n = poses.len().max(1) as f64;
    let sum: Vector3<f64> = scene
        .instruments
        .iter()
        .zip(poses)
        .map(|(spec, pose)| (pose * Point3::new(0.0, 0.0, spec.length_m)).coords)
        .sum();
    Point3::from(sum / n)
}

/// A step's compliance patch with its index.
struct ForcePatch {
    patch: Arc<CompliancePatch>,
    patch_index: Arc<Vec<u32>>,
    has_patch: bool,
}
