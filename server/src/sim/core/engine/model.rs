//! The model of a scene: the mesh, its surface, the fixed set, the
//! instruments (built from the scene's shapes and layouts) and the rest-shape
//! contact search's tree.
use super::History;
use crate::collide::contact;
use crate::collide::rays::bvh::Bvh;
use crate::collide::tool::instrument::{Instrument, RimNodes};
use crate::fem;
use crate::mesh::{BoundarySurface, TetMesh};
use crate::scene::{
    CollisionBackend, CollisionMethod, ContactGeometry, HistoryMode, ModelSpec, Region, Scene,
};
use crate::sim::core::local_model::ForceModel;
use crate::sim::core::rows::Anchors;
use crate::sim::core::snapshot::{Frame, InstrumentReaction, Snapshot, StepTimings};
use nalgebra::{Point3, Vector3};
use std::sync::Arc;

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
    /// The skull surface's nodes, when the scene has one.
    pub skull_surface: Option<fem::skull::SkullSurface>,
    /// The ties across the fissure ([`crate::fem::ties`]), in scene order.
    pub ties: Vec<fem::ties::Tie>,
    /// Per instrument: its cutting edge in the instrument frame (a blade's
    /// tip edge, [`crate::collide::tool::instrument::PlateShape::cutting_edge`]), m.
    pub blades: Vec<Option<[Point3<f64>; 2]>>,
    /// Per surface vertex, its neighbours on the surface.
    pub surface_neighbours: crate::mesh::adjacency::Csr,
    /// The rest surface the contact search runs on, when the scene's
    /// contact geometry is the rest shape ([`ContactGeometry::Rest`]).
    pub contact_rest: Option<RestContact>,
    history_mode: HistoryMode,
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
) -> Result<Instrument, ModelError> {
    let plate = spec
        .shape
        .plate(spec.thickness_m, spec.width_m, spec.length_m);
    let layout = spec.layout.layout(spec.nodes_per_face as usize);
    let rim = spec.rim.then(|| RimNodes {
        per_side: ((spec.length_m / spec.width_m * 3.0).round() as usize).clamp(4, 64),
        tip: 5,
        tip_reach: spec.thickness_m.max(0.002),
    });
    let mut instrument =
        Instrument::new(plate, layout, rim).map_err(|source| ModelError::Instrument {
            name: spec.name.clone(),
            source,
        })?;
    instrument.cap_reach(max_depth_m);
    Ok(instrument)
}

impl Model {
    /// Builds the mesh, the surface, the fixed set and the instruments.
    pub fn build(scene: &Scene) -> Result<Self, ModelError> {
        scene.check_built(&scene.name)?;
        let mut landmarks = None;
        let mesh = match &scene.model {
            ModelSpec::Cube { size_m, cells } => crate::mesh::blocks::cube(*size_m, *cells),
            ModelSpec::VValley => crate::mesh::blocks::v_valley(),
            ModelSpec::UValley => crate::mesh::blocks::u_valley(),
            ModelSpec::Phantom {
                preset,
                proven,
                spacing_m,
                refine,
                refine_near,
            } => {
                let p = crate::mesh::phantom::preset_meshed(preset, *proven, *spacing_m)?;
                landmarks = Some(p.landmarks);
                let mesh = crate::mesh::refine::uniform_times(p.mesh, *refine)?;
                refine_near.iter().try_fold(mesh, |mesh, b| {
                    let c = nalgebra::Point3::from(b.centre_m);
                    crate::mesh::refine::local(&mesh, |p| (p - c).norm() <= b.radius_m)
                })?
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
                        return Err(ModelError::UnknownLandmark {
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
                    .map_err(ModelError::RegionOfInterest)?;
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
            return Err(ModelError::Floating);
        }
        let surface = mesh.boundary();
        let mut rest_surface = Vec::new();
        surface.gather(&mesh.nodes, &mut rest_surface);
        let instruments = scene
            .instruments
            .iter()
            .map(|spec| build_instrument(spec, scene.collision.max_depth_m))
            .collect::<Result<_, _>>()?;
        let history_mode = scene.collision.history;
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
        let on = crate::scene::region::OnModel {
            mesh: &mesh,
            surface: &surface,
            fixed: &fixed_mask,
            landmarks: landmarks.as_ref(),
            to_full: to_full.as_ref().map(|t| t.0.as_slice()),
        };
        let foundation = scene
            .foundation
            .as_ref()
            .map(|f| crate::scene::region::foundation(f, &on))
            .transpose()?;
        let skull_surface = scene
            .skull
            .as_ref()
            .and_then(|s| s.surface.as_ref())
            .map(|s| crate::scene::region::skull_surface(s, &on))
            .transpose()?;
        let ties = crate::scene::ties::place(&scene.ties, &on)?;
        let blades = scene
            .instruments
            .iter()
            .map(|i| i.shape.cutting_edge(i.width_m, i.length_m))
            .collect();
        let mut from_volume = vec![u32::MAX; mesh.nodes.len()];
        for (s, &v) in surface.to_volume.iter().enumerate() {
            from_volume[v as usize] = s as u32;
        }
        let contact_rest = (scene.contact_geometry() == ContactGeometry::Rest).then(|| {
            let tree = (scene.collision.method == CollisionMethod::Bvh
                && scene.collision.backend == CollisionBackend::Cpu)
                .then(|| {
                    Arc::new(super::query::scene_bvh(
                        scene,
                        &surface.triangles,
                        &rest_surface,
                    ))
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
            skull_surface,
            ties,
            blades,
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

    /// The surface vertices' positions under the volume displacements
    /// `u` (m): each rest position plus its volume node's displacement.
    pub fn surface_at(&self, u: &[Vector3<f64>]) -> Vec<Point3<f64>> {
        self.surface
            .to_volume
            .iter()
            .zip(&self.rest_surface)
            .map(|(&v, rest)| rest + u[v as usize])
            .collect()
    }

    /// Rim source nodes of instrument `i`.
    pub fn rim_node_count(&self, i: usize) -> usize {
        self.instruments[i].len() - 2 * self.instruments[i].per_face
    }

    /// The rest state as frame `frame`, no contact.
    pub fn rest_snapshot(&self, scene: &Scene, frame: u64, sim_time_s: f64) -> Snapshot {
        let instruments = scene
            .instruments
            .iter()
            .map(InstrumentReaction::at_rest)
            .collect();
        Snapshot::solved(
            Arc::new(self.rest_surface.clone()),
            Arc::new(vec![Vector3::zeros(); self.mesh.nodes.len()]),
            None,
            ForceModel::new(
                frame,
                Arc::default(),
                Arc::default(),
                Vec::new(),
                Vec::new(),
                Anchors::default(),
                false,
                vec![(Vector3::zeros(), Vector3::zeros()); scene.instruments.len()],
            ),
            (0..self.instruments.len())
                .map(|i| self.new_history(i))
                .collect(),
            Frame::solved(
                frame,
                sim_time_s,
                &self.rest_surface,
                instruments,
                StepTimings::default(),
                0.0,
                crate::sim::core::motion::RigidPart::default(),
            )
            .with_ties(self.tie_counts(&[])),
        )
    }

    /// The ties of a frame with tie `i` in state `states[i]` (intact where
    /// `states` is shorter), no events.
    pub fn tie_counts(
        &self,
        states: &[fem::ties::TieState],
    ) -> crate::sim::core::snapshot::TieFrame {
        let mut f = crate::sim::core::snapshot::TieFrame::default();
        for (i, t) in self.ties.iter().enumerate() {
            if states.get(i).copied().unwrap_or_default() == fem::ties::TieState::Intact {
                match t.kind {
                    fem::ties::TieKind::Trabecula => f.trabeculae_intact += 1,
                    fem::ties::TieKind::Vessel => f.vessels_intact += 1,
                }
            } else {
                f.released.push(i as u32);
            }
        }
        f
    }
}

/// Errors of building a simulation.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The scene asks for a part this build lacks.
    #[error("building the model: {0}")]
    Scene(#[from] crate::scene::SceneError),
    /// The phantom preset could not be generated.
    #[error("building the model: {0}")]
    Phantom(#[from] crate::mesh::phantom::PhantomError),
    /// The model file could not be read.
    #[error("building the model: {0}")]
    ModelFile(#[from] crate::mesh::io::ModelFileError),
    /// The uniform refinement of the model (`model.refine`) failed.
    #[error("building the model: refining the mesh: {0}")]
    Refine(#[from] crate::mesh::MeshError),
    /// An instrument of the scene could not be built.
    #[error("building the model: instrument {name:?}: {source}")]
    Instrument {
        name: String,
        source: crate::collide::tool::instrument::InstrumentError,
    },
    /// A fixed region names a landmark the model does not have.
    #[error(
        "building the model: the model has no landmark named {landmark:?} (the phantom has \"brain-stem\")"
    )]
    UnknownLandmark { landmark: String },
    /// The region of interest could not be cropped.
    #[error("building the model: region of interest: {0}")]
    RegionOfInterest(#[source] crate::fem::SolveError),
    /// No node lies in the fixed regions.
    #[error("building the model: no node lies in the fixed region(s); the model would float")]
    Floating,
    /// The elastic foundation's regions could not be resolved.
    #[error("building the model: {0}")]
    Foundation(#[from] crate::scene::region::RegionError),
    /// The scene's ties could not be placed.
    #[error("building the model: {0}")]
    Ties(#[from] crate::scene::ties::TieError),
    /// The solver could not be set up.
    #[error("setting up the solver: {0}")]
    Solver(#[source] crate::fem::SolveError),
}
