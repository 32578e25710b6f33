//! The collision stage of each loop: the ray backend a scene asks for, the
//! published surface trees, and [`ContactQuery`], one loop's contact search
//! over a snapshot.
use super::History;
use super::model::Model;
use crate::collide::contact::history::Stage;
use crate::collide::contact::{ContactOutput, ContactRule, DetectOptions, Tool, Workspace};
use crate::collide::rays::brute::BruteForce;
use crate::collide::rays::bvh::{Bvh, BvhView};
use crate::collide::{RayBackend, contact};
use crate::scene::{CollisionBackend, CollisionMethod, ContactGeometry, ContactLaw, Scene};
use crate::sim::core::snapshot::Snapshot;
use faer::Par;
use nalgebra::{Isometry3, Point3};
use std::sync::Arc;

/// A CPU BVH over a surface the model checked at load (`triangles` at
/// `positions`), walking parallel rays as the scene's `collision.traversal`
/// says.
pub fn scene_bvh(scene: &Scene, triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Bvh {
    let mut bvh = Bvh::new(triangles, positions).expect("surface checked at load");
    bvh.set_traversal(scene.collision.traversal);
    bvh
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
            CollisionMethod::Bvh => Box::new(scene_bvh(scene, tris, positions)),
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
                CollisionMethod::Brute => crate::collide::rays::gpu::GpuMethod::Brute,
                CollisionMethod::Bvh => crate::collide::rays::gpu::GpuMethod::Bvh,
            };
            // Logs a warning with the reason when it falls back.
            let backend =
                crate::collide::rays::gpu::backend_or_cpu(gpu_method, tris, positions, cpu);
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
                current: Arc::new(scene_bvh(
                    scene,
                    &model.surface.triangles,
                    &model.rest_surface,
                )),
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
