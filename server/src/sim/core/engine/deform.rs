//! The deformation stage: the FEM solver of the scene's strategy, the
//! choice of the nodes a step's compliance patch covers, and the penalty
//! measure of a row.
use super::model::Model;
use super::model::ModelError;
use crate::collide::Nearby;
use crate::fem::compliance::ColumnPolicy;
use crate::fem::{self, CompliancePatch, ContactAnswer, ContactRow, DeformationSolver, RowKind};
use crate::scene::Scene;
use crate::sim::core::rows::Row;
use nalgebra::Vector3;
use std::sync::Arc;

/// The volume nodes a step's compliance patch covers (`near`) and those
/// whose columns are computed ahead of contact (`ahead`), gathered from the
/// step's rows and the vertices near the plates.
#[derive(Debug, Default)]
pub struct PatchNodes {
    near: Vec<u32>,
    exact: Vec<u32>,
    ahead: Vec<u32>,
}

impl PatchNodes {
    /// Every node a row names; the plates' rows with their surface
    /// neighbours (a contact slides onto them), the ties' and the skull's
    /// alone (their rows never move: each stays at its node).
    pub fn add_rows<'a>(&mut self, rows: impl IntoIterator<Item = &'a Row>) {
        for r in rows {
            let to = if r.owner == super::rows::TIE_OWNER || r.owner == super::rows::SKULL_OWNER {
                &mut self.exact
            } else {
                &mut self.near
            };
            to.extend(r.row.nodes().map(|(n, _)| n));
        }
    }

    /// Vertices near a plate: within `near_m` (m) of a face in the patch,
    /// farther ones ahead.
    pub fn add_nearby(&mut self, nearby: &[Nearby], near_m: f64) {
        for n in nearby {
            if n.distance_m <= near_m {
                self.near.push(n.volume_node);
            } else {
                self.ahead.push(n.volume_node);
            }
        }
    }

    /// The patch's nodes, with one ring of surface neighbours (a plate's
    /// outline that moves within the interval crosses triangles beyond the
    /// vertices the step found, and a polygon point there names all three),
    /// and the nodes ahead; each sorted, without repeats or fixed nodes.
    pub fn finish(self, model: &Model) -> (Vec<u32>, Vec<u32>) {
        let Self {
            near: mut patch,
            exact,
            mut ahead,
        } = self;
        patch.sort_unstable();
        patch.dedup();
        let found = patch.len();
        for i in 0..found {
            let s = model.from_volume[patch[i] as usize];
            if s != u32::MAX {
                patch.extend(
                    model
                        .surface_neighbours
                        .row(s as usize)
                        .iter()
                        .map(|&w| model.surface.to_volume[w as usize]),
                );
            }
        }
        patch.extend(exact);
        for nodes in [&mut patch, &mut ahead] {
            nodes.sort_unstable();
            nodes.dedup();
            nodes.retain(|&v| !model.fixed_mask[v as usize]);
        }
        (patch, ahead)
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
    ) -> Result<Self, ModelError> {
        let strategy = scene.solver.strategy;
        let (material, tissues) = scene.material.to_fem();
        let mut options = fem::SolverOptions {
            tissues,
            ..Default::default()
        };
        options.iterative.tolerance = scene.solver.tolerance;
        options.iterative.max_outer = scene.solver.max_iterations;
        options.foundation = model.foundation.clone();
        options.element = scene.solver.element;
        // Every pair a tie may join, for the strategies that hold ties as
        // springs of their energy (they couple them in their pattern).
        options.tie_pairs = crate::fem::ties::TieRows::all(&model.ties)
            .pairs
            .iter()
            .map(|p| [p.a, p.b])
            .collect();
        let mut solver = fem::build_solver(strategy, &model.mesh, material, &model.fixed, &options)
            .map_err(ModelError::Solver)?;
        solver.set_column_policy(columns, hook);
        // The skull's nodes never move: their compliance along their
        // normals is computed once here, so that the skull's rows cost a
        // step and the force loop no column (DESIGN.md section 3c).
        if let Some(s) = model.skull_surface.as_ref().filter(|s| !s.nodes.is_empty()) {
            solver.hold_normals(&s.nodes).map_err(ModelError::Solver)?;
        }
        Ok(Self {
            solver,
            answer: ContactAnswer::default(),
            fem_rows: Vec::new(),
            patch: CompliancePatch::default(),
        })
    }

    /// Gives the intact ties to a strategy that holds them as springs of
    /// its energy; `false` when it takes them as contact rows
    /// ([`fem::DeformationSolver::set_tie_springs`]).
    pub fn set_tie_springs(&mut self, springs: &crate::fem::ties::TieSprings) -> bool {
        self.solver.set_tie_springs(springs)
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

    /// Declares nodes every later patch holds (the ties' nodes:
    /// [`fem::DeformationSolver::share_patch_nodes`]).
    pub fn share_patch_nodes(&mut self, nodes: &[u32]) {
        self.solver.share_patch_nodes(nodes);
    }

    /// Asks for the compliance of `nodes` ahead of contact.
    pub fn prefetch(&mut self, nodes: &[u32]) {
        self.solver.prefetch(nodes);
    }

    /// Bytes the strategy's caches hold ([`fem::DeformationSolver::cache_bytes`]).
    pub fn cache_bytes(&self) -> usize {
        self.solver.cache_bytes()
    }

    /// Bytes the strategy holds for the skull ([`fem::DeformationSolver::held_bytes`]).
    pub fn held_bytes(&self) -> usize {
        self.solver.held_bytes()
    }

    /// Nodes whose compliance columns the strategy has solved
    /// ([`fem::DeformationSolver::columns_solved`]).
    pub fn columns_solved(&self) -> u64 {
        self.solver.columns_solved()
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
    // A row with its own spring (a tie) answers through both in series.
    let c = row.row.compliance_m_per_n;
    let k = if c > 0.0 && k > 0.0 {
        1.0 / (1.0 / k + c)
    } else {
        k
    };
    let g = row.row.gap_free_m + row.row.normal_motion(u);
    match row.row.kind {
        RowKind::Unilateral => k * (-g).max(0.0),
        RowKind::Bilateral => -k * g,
        _ => 0.0,
    }
}
