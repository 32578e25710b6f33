//! The engine a scene asks for, composed from the library stages: the model
//! (mesh, surface, instruments), the collision stage of each loop, the
//! contact rows, and the deformation stage (the contact problem's solve,
//! the compliance patch the force loops solve on).
//!
//! "Model only what a scene requires": the skull's rows exist only when the
//! scene names it; each instrument's rays are cast only for that
//! instrument; the force loop of an instrument queries that instrument
//! alone.
//!
//! [`model`] builds the model, [`query`] is the collision stage, [`rules`]
//! makes the contact rows, [`deform`] is the deformation stage; this module
//! composes them into the step ([`StepEngine`]).

use super::injury::{InjuryGeometry, InjuryStage};
use super::local_model::ForceModel;
use super::rows::{self, Anchors, FreePositions, Row};
use super::snapshot::{Frame, InstrumentReaction, Snapshot, StepTimings};
use crate::collide::RayBackend;
use crate::collide::contact::{self, ContactOutput};
use crate::collide::rays::bvh::Bvh;
use crate::fem::compliance::ColumnPolicy;
use crate::fem::{self, CompliancePatch, RowKind};
use crate::scene::{HistoryMode, Scene};
use faer::Par;
use nalgebra::{Isometry3, Point3, Vector3};
use std::sync::Arc;
use std::time::Instant;

/// Contact history flags of one instrument.
pub type History = crate::collide::contact::history::History;

pub mod deform;
pub mod model;
pub mod query;
pub mod relax;
pub mod rules;
pub mod ties;

pub use deform::{Deformer, PatchNodes, penalty};
pub use model::{Model, ModelError, RestContact};
pub use query::{ContactQuery, SurfaceBvhs, detect_options, ray_backend, scene_bvh};
pub use rules::{RowRule, SkullRows};
pub use ties::{TEAR_ROUNDS, TieCuts, TieStage, TiesAtStep};

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
    /// Bytes the solver's caches hold after the step.
    pub cache_bytes: usize,
    /// Nodes whose compliance columns the solver has solved since it was
    /// built, after the step (the skull's held normals are not columns).
    pub columns_solved: u64,
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
    ties: TieStage,
    /// Whether the strategy holds the ties as springs of its energy (the
    /// nonlinear ones) rather than as contact rows.
    tie_springs: bool,
    injury: InjuryStage,
    next_frame: u64,
    rows: Vec<Row>,
    warm: Vec<f64>,
    extra: Vec<u32>,
    lambda: Vec<f64>,
    /// The contact geometry's relaxation within the step.
    relax: relax::Relaxation,
    /// Its residuals of a round (reused).
    residuals: Vec<(u64, [f64; 3])>,
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
    /// The intact ties into the step's problem: springs of the strategy's
    /// energy (the nonlinear strategies, at their true length and
    /// direction) or rows of the contact problem (the linear ones, at
    /// rest; [`crate::fem::ties`]).
    fn ties_into_problem(&mut self, model: &Model) {
        if self.tie_springs {
            self.deformer.set_tie_springs(&self.ties.springs());
        } else {
            self.ties.push_rows(model, &mut self.rows);
        }
    }

    /// The step of `scene` over `model` (factorizes the solver). `columns`
    /// and `hook` as in [`Deformer::new`]; `query` casts on the scene's
    /// backend unless the caller gives one.
    pub fn new(
        scene: &Scene,
        model: Arc<Model>,
        columns: ColumnPolicy,
        hook: Option<Arc<dyn Fn() + Send + Sync>>,
        backend: Option<Box<dyn RayBackend>>,
    ) -> Result<Self, ModelError> {
        let mut deformer = Deformer::new(scene, &model, columns, hook)?;
        let tie_springs = !model.ties.is_empty() && deformer.set_tie_springs(&Default::default());
        // The ties' rows are in every step's problem and their nodes in
        // every patch: their blocks among themselves are computed once.
        let tie_nodes: Vec<u32> = model.ties.iter().flat_map(|t| [t.a, t.b]).collect();
        if !tie_nodes.is_empty() {
            deformer.share_patch_nodes(&tie_nodes);
        }
        let query = match backend {
            Some(b) => ContactQuery::with_backend(scene, b),
            None => ContactQuery::new(scene, Par::rayon(0)),
        };
        // The search casts on a CPU tree of its own (every backend gives the
        // same answers).
        let search = ContactQuery::with_backend(
            scene,
            Box::new(query::scene_bvh(
                scene,
                &model.surface.triangles,
                &model.rest_surface,
            )),
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
            ties: TieStage::new(&model),
            tie_springs,
            injury: InjuryStage::new(
                Arc::new(InjuryGeometry::new(
                    &model.mesh,
                    &model.surface,
                    &model.from_volume,
                )),
                scene.assessment,
            ),
            next_frame: 0,
            rows: Vec::new(),
            warm: Vec::new(),
            extra: Vec::new(),
            lambda: Vec::new(),
            relax: relax::Relaxation::default(),
            residuals: Vec::new(),
            model,
        })
    }

    /// The model.
    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// Gives this engine the ties another engine's force loops see now
    /// (`other`: its latest snapshot's) and stops its own tearing, for a
    /// reference full solve of that engine's samples
    /// ([`TieStage::mirror`]). From the next step on.
    pub fn mirror_ties(&mut self, other: &TiesAtStep) {
        self.ties.mirror(&self.model, other);
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
        self.ties = TieStage::new(&self.model);
        self.injury.reset();
        let frame = self.next_frame;
        self.next_frame += 1;
        let mut snap = self.model.rest_snapshot(&self.scene, frame, sim_time_s);
        snap.surface_bvh = self.bvhs.as_mut().map(|b| b.fit(&snap.surface));
        // A strategy with a compliance operator answers contacts before the
        // first step too (with penalties until its columns exist).
        let patch = self.deformer.patch(&[]).is_some();
        if let Some(fm) = Arc::get_mut(&mut snap.force_model) {
            fm.has_patch = patch;
            fm.ties = self.ties.at_step();
        }
        snap
    }

    /// One deformation step at `sim_time_s` from `prev`: instrument `i` at
    /// `poses[i]` with the force loop's history `histories[i]` (force-rate
    /// mode; `None`: an instrument at home, or the paper's mode, uses the
    /// step's own history).
    ///
    /// The stages, in order: `collide` (every instrument's query at its
    /// pose) and its [`RowRule`] rows; `join_rows` (the skull's and
    /// the ties' rows, the warm start); `solve_contact` (the
    /// contact problem to its fixed point: skull rounds, searches on the
    /// solved shape, tears); `refresh` (multipliers, anchors, the
    /// new surface and its tree, the force loops' compliance patch); and
    /// `snapshot`. A failed solve publishes the last good state
    /// ([`Snapshot::failed`]).
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
        let paper_mode = self.scene.collision.history == HistoryMode::PaperFaithful;

        let t0 = Instant::now();
        let collision = tracing::debug_span!("collision").in_scope(|| {
            collide(
                &mut self.query,
                &mut self.paper_history,
                paper_mode,
                &model,
                prev,
                poses,
                histories,
            )
        });
        let collision_us = t0.elapsed().as_secs_f64() * 1e6;
        let t1 = Instant::now();
        self.rows.clear();
        self.rule.rows(
            &model,
            collision.contacts,
            &FreePositions::Rest(&model.mesh.nodes),
            &prev.displacements,
            &self.anchors,
            poses,
            &mut self.rows,
        );
        let mut n_instrument_rows = self.rows.len();
        let counts = contact_counts(collision.contacts, model.instruments.len());
        let nearby = collision.contacts.nearby.clone();
        let Collision { mut after, own, .. } = collision;

        self.join_rows(&model, prev, sim_time_s);
        let (result, rounds) =
            self.solve_contact(&model, poses, &after, &mut n_instrument_rows, sim_time_s);
        let solve_us = t1.elapsed().as_secs_f64() * 1e6;
        tracing::debug!(
            frame,
            solves = rounds.solves,
            searches = rounds.searches,
            tear_rounds = rounds.tears,
            rows = self.rows.len(),
            solve_us,
            "step solved"
        );
        let timings = |total: f64| StepTimings {
            collision_us,
            solve_us,
            total_us: total,
            assess_us: 0.0,
        };
        if let Err(e) = result {
            tracing::warn!(frame, error = %e, "deformation step failed; keeping the last good state");
            let failed = prev.failed(
                frame,
                sim_time_s,
                timings(started.elapsed().as_secs_f64() * 1e6),
                e.to_string(),
            );
            return (failed, None);
        }

        let fresh = self.refresh(
            &model,
            prev,
            poses,
            &own,
            &mut after,
            &nearby,
            n_instrument_rows,
        );
        let report = StepReport {
            rows: self.rows.len(),
            pending: fresh.pending.len(),
            iterations: fresh.iterations,
            rounds: rounds.solves,
            check: fresh.check,
            patch_nodes: fresh.patch.patch.nodes.len(),
            cache_bytes: self.deformer.cache_bytes(),
            columns_solved: self.deformer.columns_solved(),
        };
        let total_us = started.elapsed().as_secs_f64() * 1e6;
        let snap = self.snapshot(
            frame,
            sim_time_s,
            &counts,
            poses,
            fresh.surface,
            fresh.surface_bvh,
            fresh.displacements,
            fresh.patch,
            &fresh.pending,
            timings(total_us),
        );
        (snap, Some(report))
    }

    /// The rows that join the instruments' (the step's second stage): the
    /// skull's, then the intact ties' less those the blades cut since the
    /// last step; and the warm start of them all, each row's multiplier of
    /// the last step by key.
    fn join_rows(&mut self, model: &Model, prev: &Snapshot, sim_time_s: f64) {
        if let Some(skull) = &self.skull {
            skull.rows(model, &prev.displacements, &[], &mut self.rows);
        }
        self.ties.take_cuts(model, sim_time_s);
        self.ties_into_problem(model);
        let last = &prev.force_model;
        self.warm.clear();
        self.warm.extend(
            self.rows
                .iter()
                .map(|r| last.step_multiplier(r.key).unwrap_or(0.0)),
        );
    }

    /// The contact problem to its fixed point (the step's third stage):
    /// solve; skull nodes leaving the sphere join and it solves again (at
    /// most [`SKULL_ROUNDS`] solves); a search on the solved shape adds the
    /// rows it finds violated (at most [`CONTACT_SEARCHES`]); then ties
    /// stretched to their rupture tear and it starts over without them (at
    /// most [`TEAR_ROUNDS`] times). `after`: the histories after the
    /// step's query.
    fn solve_contact(
        &mut self,
        model: &Model,
        poses: &[Isometry3<f64>],
        after: &[History],
        n_instrument_rows: &mut usize,
        sim_time_s: f64,
    ) -> (Result<(), fem::SolveError>, Rounds) {
        let mut rounds = Rounds::default();
        self.relax.reset();
        let tips = tips_of(&self.scene, poses);
        let result = 'tear: loop {
            let solved = loop {
                rounds.solves += 1;
                if let Err(e) = self.deformer.solve(&self.rows, &self.warm) {
                    break Err(e);
                }
                // Skull nodes leaving the sphere join the problem.
                if let Some(skull) = &self.skull {
                    let u = self.deformer.displacements();
                    skull.violations(
                        model,
                        u,
                        &self.rows,
                        1e-9 * skull.band_m.max(1e-6),
                        &mut self.extra,
                    );
                    if !self.extra.is_empty() && rounds.solves < SKULL_ROUNDS {
                        let extra = std::mem::take(&mut self.extra);
                        let u = self.deformer.displacements().to_vec();
                        skull.rows(model, &u, &extra, &mut self.rows);
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
                if model.contact_rest.is_none() && rounds.searches < CONTACT_SEARCHES {
                    rounds.searches += 1;
                    if self.search_solved(model, poses, after, n_instrument_rows) {
                        continue;
                    }
                }
                break Ok(());
            };
            if solved.is_err() || !self.ties.tears() {
                break solved;
            }
            // Ties stretched to their rupture tear, and the step solves again
            // without them (the load they carried passes to the others).
            // Only an instrument that pushes the tissue can tear a tie.
            let mut pushing = vec![false; tips.len()];
            for (r, &l) in self.rows.iter().zip(&self.deformer.answer().multipliers) {
                if l != 0.0 {
                    if let Some(p) = pushing.get_mut(r.owner as usize) {
                        *p = true;
                    }
                }
            }
            let torn = self.ties.tear(
                model,
                self.deformer.displacements(),
                &tips,
                &pushing,
                sim_time_s,
            );
            if !torn || rounds.tears >= TEAR_ROUNDS {
                break 'tear solved;
            }
            rounds.tears += 1;
            let old = self.multipliers_by_key();
            self.rows.retain(|r| r.owner != rows::TIE_OWNER);
            self.ties_into_problem(model);
            self.warm_from(&old);
            self.relax.reset();
        };
        (result, rounds)
    }

    /// What a solved step publishes (its fourth stage): the multipliers
    /// (penalties for rows whose compliance is pending), the paper
    /// histories' seeds, friction's anchors, the displacements, the new
    /// surface and its tree, and the force loops' compliance patch, which
    /// covers the rows a query at the step's poses finds on the new
    /// surface too (`after`: the histories after the step's query; `own`:
    /// the instruments whose history is the step's own).
    #[allow(clippy::too_many_arguments)]
    fn refresh(
        &mut self,
        model: &Model,
        prev: &Snapshot,
        poses: &[Isometry3<f64>],
        own: &[bool],
        after: &mut [History],
        nearby: &[contact::Nearby],
        n_instrument_rows: usize,
    ) -> Refreshed {
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
            self.lambda[p as usize] = penalty(model, &self.rows[p as usize], &prev.displacements);
        }
        let pending = answer.pending.clone();
        let check = answer.report;
        let iterations = self.deformer.iterations();
        let displacements = Arc::new(self.deformer.displacements().to_vec());
        if self.rule.friction.is_some() {
            self.update_anchors(model, poses, &displacements, n_instrument_rows);
        }
        // The new surface and its tree; the force loops query it, so the
        // patch covers the rows a query at the step's poses finds on it too.
        let surface = Arc::new(model.surface_at(&displacements));
        let surface_bvh =
            tracing::debug_span!("refit").in_scope(|| self.bvhs.as_mut().map(|b| b.fit(&surface)));
        let mut selection = deform::PatchNodes::default();
        let band2 = 2.0 * self.scene.contact.band_m;
        // The skull's rows without force stay out of the force loops'
        // problem (`ForceLoop::solve`), and so out of the patch.
        selection.add_rows(
            self.rows
                .iter()
                .zip(&self.lambda)
                .filter(|(r, l)| r.owner != rows::SKULL_OWNER || **l > 0.0)
                .map(|(r, _)| r),
        );
        selection.add_nearby(nearby, band2);
        // (A linearized contact finds the same rows on any shape.)
        if model.contact_rest.is_none() {
            let post = self
                .query
                .query_all_on(model, &surface, surface_bvh.as_ref(), poses, after);
            let mut post_rows = Vec::new();
            self.rule.rows(
                model,
                post,
                &FreePositions::Rest(&model.mesh.nodes),
                &prev.displacements,
                &self.anchors,
                poses,
                &mut post_rows,
            );
            selection.add_rows(&post_rows);
            selection.add_nearby(&post.nearby, band2);
        }
        let (patch_nodes, ahead) = selection.finish(model);
        let patch = self.deformer.patch(&patch_nodes);
        self.deformer.prefetch(&ahead);
        let has_patch = patch.is_some();
        let patch = Arc::new(patch.unwrap_or_default());
        let mut patch_index = vec![u32::MAX; model.mesh.nodes.len()];
        for (i, &v) in patch.nodes.iter().enumerate() {
            patch_index[v as usize] = i as u32;
        }
        Refreshed {
            displacements,
            surface,
            surface_bvh,
            patch: ForcePatch {
                patch,
                patch_index: Arc::new(patch_index),
                has_patch,
            },
            pending,
            check,
            iterations,
        }
    }

    /// The contact geometry's fixed point, one round of [`Self::step`]:
    /// queries the solved shape at `poses` (with copies of the histories
    /// after the step's query) and, unless its instrument rows are the
    /// problem's (same keys, point weights within
    /// [`GEOMETRY_TOLERANCE`]), makes them the problem's, each point row
    /// moved from the problem's row of its key toward the found one by
    /// Aitken's relaxation ([`relax`], [`rows::toward`]: a corner's tissue
    /// point moves with the shape it pushes, and the plain iteration can
    /// swing between two shapes); the skull's rows follow.
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
        let surface = Arc::new(model.surface_at(u));
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
        self.residuals.clear();
        for r in &post {
            match by_key.get(&r.key) {
                Some(&i) => {
                    let o = &old[i];
                    if r.row.is_point() || o.row.is_point() {
                        let dw = [0, 1, 2].map(|k| r.triangle.1[k] - o.triangle.1[k]);
                        if dw.iter().any(|d| d.abs() > GEOMETRY_TOLERANCE) {
                            same = false;
                        }
                        self.residuals.push((r.key, dw));
                    }
                }
                None => same = false,
            }
        }
        if same {
            return false;
        }
        let omega = self.relax.omega(&self.residuals);
        for r in post.iter_mut() {
            if let Some(&i) = by_key.get(&r.key) {
                let o = &old[i];
                if r.row.is_point() || o.row.is_point() {
                    *r = rows::toward(o, r, omega, &free, &model.fixed_mask);
                }
            }
        }
        let old_lambda = self.multipliers_by_key();
        let skull: Vec<Row> = self.rows[*n_instrument_rows..].to_vec();
        self.rows.clear();
        rows::append(&mut self.rows, &post);
        *n_instrument_rows = self.rows.len();
        rows::append(&mut self.rows, &skull);
        self.warm_from(&old_lambda);
        true
    }

    /// The last solve's multiplier of each row, by key.
    fn multipliers_by_key(&self) -> std::collections::HashMap<u64, f64> {
        self.rows
            .iter()
            .zip(&self.deformer.answer().multipliers)
            .map(|(r, &l)| (r.key, l))
            .collect()
    }

    /// The warm start of the rows now in the problem: each row's multiplier
    /// in `old` (by key), 0 for a new row.
    fn warm_from(&mut self, old: &std::collections::HashMap<u64, f64>) {
        self.warm.clear();
        self.warm.extend(
            self.rows
                .iter()
                .map(|r| old.get(&r.key).copied().unwrap_or(0.0)),
        );
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
        let assess_started = Instant::now();
        let (pressures, strain, picture) = self.injury.measure(
            sim_time_s,
            &self.rows,
            &self.lambda,
            self.scene.instruments.len(),
            &displacements,
            &surface,
        );
        let timings = StepTimings {
            assess_us: assess_started.elapsed().as_secs_f64() * 1e6,
            ..timings
        };
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
                    pressure: pressures[k],
                }
            })
            .collect();
        let rigid = super::motion::RigidPart::of(
            &model.rest_surface,
            &surface,
            tips_centre(&self.scene, poses),
        );
        let summary = Frame::solved(
            frame,
            sim_time_s,
            &surface,
            instruments,
            timings,
            max_d,
            rigid,
        )
        .with_ties(self.ties.frame(model))
        .with_strain(strain, picture);
        let mut force_model = ForceModel::new(
            frame,
            patch.patch,
            patch.patch_index,
            self.rows.clone(),
            self.lambda.clone(),
            self.anchors.clone(),
            patch.has_patch,
            step_force,
        );
        force_model.ties = self.ties.at_step();
        Snapshot::solved(
            surface,
            displacements,
            surface_bvh,
            force_model,
            self.paper_history.clone(),
            summary,
        )
    }
}

/// The step's first stage: every instrument's query at `poses[i]` on
/// `prev`'s shape. Instrument `i` uses the force loop's history
/// `histories[i]` (force-rate mode) or, in the paper's mode or with
/// `None`, the step's own (`paper_history[i]`, which this updates).
fn collide<'q>(
    query: &'q mut ContactQuery,
    paper_history: &mut [History],
    paper_mode: bool,
    model: &Model,
    prev: &Snapshot,
    poses: &[Isometry3<f64>],
    histories: Vec<Option<History>>,
) -> Collision<'q> {
    let own: Vec<bool> = histories
        .iter()
        .map(|h| paper_mode || h.is_none())
        .collect();
    let mut step_histories: Vec<History> = histories
        .into_iter()
        .enumerate()
        .map(|(i, h)| match h {
            Some(h) if !paper_mode => h,
            _ => paper_history[i].clone(),
        })
        .collect();
    let contacts = query.query_all(model, prev, poses, &mut step_histories);
    let after = step_histories.clone();
    for (i, h) in step_histories.into_iter().enumerate() {
        if own[i] {
            paper_history[i] = h;
        }
    }
    Collision {
        contacts,
        after,
        own,
    }
}

/// What [`collide`] found.
struct Collision<'q> {
    /// The query's output (rows, pairs, nearby vertices).
    contacts: &'q ContactOutput,
    /// Every instrument's history after the query.
    after: Vec<History>,
    /// Whether instrument `i`'s history is the step's own.
    own: Vec<bool>,
}

/// Each instrument's collision pairs and culled pairs.
fn contact_counts(contacts: &ContactOutput, instruments: usize) -> Vec<(u32, u32)> {
    (0..instruments)
        .map(|k| {
            let pairs = contacts.pairs_of(k as u16).count() as u32;
            let culled = contacts
                .cancelled
                .iter()
                .filter(|p| p.instrument as usize == k)
                .count() as u32;
            (pairs, culled)
        })
        .collect()
}

/// The solves of one step's contact problem.
#[derive(Debug, Clone, Copy, Default)]
struct Rounds {
    /// Solves in all.
    solves: u32,
    /// Searches on a solved shape.
    searches: u32,
    /// Rounds that tore ties.
    tears: u32,
}

/// What [`StepEngine::refresh`] publishes of a solved step.
struct Refreshed {
    displacements: Arc<Vec<Vector3<f64>>>,
    surface: Arc<Vec<Point3<f64>>>,
    surface_bvh: Option<Arc<Bvh>>,
    patch: ForcePatch,
    /// Rows answered by a penalty.
    pending: Vec<u32>,
    check: fem::lcp::Report,
    iterations: u32,
}

/// The instruments' tips (`+z` of the plate frame at its length from the
/// handle), m.
fn tips_of(scene: &Scene, poses: &[Isometry3<f64>]) -> Vec<Point3<f64>> {
    scene
        .instruments
        .iter()
        .zip(poses)
        .map(|(spec, pose)| pose * Point3::new(0.0, 0.0, spec.length_m))
        .collect()
}

/// The mean of the instruments' tips, m: the fissure's centre while they
/// work in it.
fn tips_centre(scene: &Scene, poses: &[Isometry3<f64>]) -> Point3<f64> {
    let n = poses.len().max(1) as f64;
    let sum: Vector3<f64> = tips_of(scene, poses).iter().map(|p| p.coords).sum();
    Point3::from(sum / n)
}

/// A step's compliance patch with its index.
struct ForcePatch {
    patch: Arc<CompliancePatch>,
    patch_index: Arc<Vec<u32>>,
    has_patch: bool,
}
