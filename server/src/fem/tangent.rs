//! The tangent compliance patch of the nonlinear strategies (`corotational`,
//! `neo-hookean`): the force loop's local model between their steps.
//!
//! At the last step's equilibrium `u*` the internal force `f(u)` balances the
//! contact forces `r` (N, on the tissue). To first order a change of the
//! contact forces to `f_c` moves node `i` to
//! `x_i = X_i + u*_i + sum_j C_ij (f_c,j - r_j)`, with `C = K_t^-1` the
//! inverse of the tangent stiffness `K_t = df/du` at `u*` under the fixed
//! supports (m/N). So the patch's blocks are `C_ij` and its free positions
//! `X_i + u*_i - sum_j C_ij r_j` (the [`CompliancePatch`] convention), and
//! the force loop's contact problem is the linearization of the full one
//! about the last step: exact for a linear model, first-order accurate for
//! the nonlinear ones (its error against a full solve at every sample is
//! what `fissure bench haptic --strategy` measures).
//!
//! Cost: one assembly and one numeric Cholesky factorization of `K_t` per
//! step (on the symbolic analysis of the model's pattern, done once), then
//! `3 m` triangular solves for `m` patch nodes, in batches of
//! [`BATCH_NODES`] nodes (`3 x 16` right-hand sides, to bound the memory).
//! The factorization is made when a patch is first asked for after a step,
//! not at the step itself, and `neo-hookean` keeps it over steps that end
//! in the same state to the bit (at rest before the first contact) and
//! makes none for a patch without free nodes; it preconditions the next
//! step's Newton iterations ([`TangentPatch::factor_mut`]). A tangent that is not positive definite (an
//! element near collapse under neo-Hookean) falls back to the rest stiffness
//! there, as the Newton iteration does. The tangent holds every term of
//! the strategy's energy: the tissue's elements, the springs of an elastic
//! foundation and of the ties, and the nodal part of the nodal-pressure
//! element (`neo-hookean`).

use super::constraint::Frame;
use super::contact::CompliancePatch;
use super::element::ElementMatrix;
use super::factor::SparseLlt;
use super::model::Model;
use super::nodal_pressure::{Eliminated, NodalPressure, NodalVolumes};
use super::ties::TieSprings;
use super::{SolveError, assembly::node_vec};
use nalgebra::{Matrix3, Point3, Vector3};

/// Patch nodes whose columns one batch of triangular solves takes.
pub const BATCH_NODES: usize = 16;

/// The factor of the supported tangent stiffness and its workspaces.
#[derive(Debug)]
pub struct TangentPatch {
    frame: Frame,
    factor: SparseLlt,
    values: Vec<f64>,
    rhs: Vec<f64>,
    zeros: Vec<f64>,
    cols: Vec<f64>,
    /// Workspace of the nodal-pressure scatter.
    scratch: Vec<Vector3<f64>>,
    /// Whether the factor is of the last step's state.
    fresh: bool,
}

impl TangentPatch {
    /// Workspaces for `model` (symbolic analysis of its pattern).
    pub fn new(model: &Model) -> Result<Self, SolveError> {
        let n = model.pattern.n_dofs;
        Ok(Self {
            frame: Frame::new(model.support.clone()),
            factor: SparseLlt::new(&model.pattern)?,
            values: vec![0.0; model.pattern.nnz()],
            rhs: vec![0.0; n],
            zeros: vec![0.0; n],
            cols: Vec::new(),
            scratch: Vec::new(),
            fresh: false,
        })
    }

    /// Whether the factor is of the current state (the next
    /// [`Self::refactor`] does nothing).
    pub fn is_fresh(&self) -> bool {
        self.fresh
    }

    /// The factor of the last [`Self::refactor`], whether or not the state
    /// moved since (`None` before the first or after a failed one): a
    /// preconditioner for a nearby tangent.
    pub fn factor_mut(&mut self) -> Option<&mut SparseLlt> {
        self.factor.is_factored().then_some(&mut self.factor)
    }

    /// The state moved (a step, a reset): the next patch refactors.
    pub fn invalidate(&mut self) {
        self.fresh = false;
    }

    /// Assembles `sum_e k(e)` (the element tangents, global basis, N/m),
    /// the springs of an elastic foundation (`model.foundation`), the
    /// tangents of the tie springs `springs` at displacement `u` (DOF
    /// vector, m; [`TieSprings::elements`]) and, with the nodal-pressure
    /// element, the rank-one nodal part of `nodal` (evaluated at `u`;
    /// [`NodalVolumes::scatter`]) with the supports eliminated and factors
    /// it, unless the factor is of the current state already. When `k`
    /// gives `None` for an element or the sum is not positive definite, the
    /// rest stiffness is used instead: `model.kel` (which holds the
    /// foundation's springs), the linear nodal part `K_vol` and the tie
    /// springs.
    pub fn refactor(
        &mut self,
        model: &Model,
        mut k: impl FnMut(usize) -> Option<ElementMatrix>,
        springs: &TieSprings,
        nodal: Option<(&NodalPressure, &NodalVolumes)>,
        u: &[f64],
    ) -> Result<(), SolveError> {
        if self.fresh {
            return Ok(());
        }
        let mut assemble = |this: &mut Self, rest: bool| -> bool {
            this.values.fill(0.0);
            this.rhs.fill(0.0);
            for (e, t) in model.tets.iter().enumerate() {
                let tangent;
                let ke = if rest {
                    &model.kel[e]
                } else {
                    match k(e) {
                        Some(ke) => {
                            // The foundation's springs (in `kel` already).
                            tangent = match model.foundation.matrix_of(e) {
                                Some(kf) => ke + kf,
                                None => ke,
                            };
                            &tangent
                        }
                        None => return false,
                    }
                };
                this.frame.scatter(
                    &model.pattern,
                    e,
                    t,
                    ke,
                    &this.zeros,
                    &mut this.values,
                    &mut this.rhs,
                );
            }
            if let Some(p) = &model.pressure {
                let out = Eliminated {
                    frame: &this.frame,
                    pattern: &model.pattern,
                    lift: &this.zeros,
                    values: &mut this.values,
                    rhs: &mut this.rhs,
                };
                match nodal {
                    Some((np, state)) if !rest => state.scatter(np, out, &mut this.scratch),
                    _ => p.scatter_into(out, &mut this.scratch),
                }
            }
            // The ties' springs (pseudo-elements after the tetrahedra,
            // [`super::ties::TieSprings::elements`]), positive
            // semi-definite, in the rest fallback too.
            for (i, t, ke) in springs.elements(&model.rest, u) {
                this.frame.scatter(
                    &model.pattern,
                    model.tets.len() + i,
                    &t,
                    &ke,
                    &this.zeros,
                    &mut this.values,
                    &mut this.rhs,
                );
            }
            this.frame
                .finish(&model.pattern, &this.zeros, &mut this.values, &mut this.rhs);
            true
        };
        if !assemble(self, false) || self.factor.factorize(&model.pattern, &self.values).is_err() {
            assemble(self, true);
            self.factor.factorize(&model.pattern, &self.values)?;
        }
        self.fresh = true;
        Ok(())
    }

    /// Fills `patch` over `nodes` (duplicates and fully supported nodes
    /// left out) from the factor of [`Self::refactor`]: blocks `C_ij` and
    /// free positions `X_i + u_i - sum_j C_ij r_j`, with `u` every node's
    /// displacement (m) and `force` the internal force at it (DOF vector,
    /// N: the contact forces at equilibrium).
    pub fn fill(
        &mut self,
        model: &Model,
        nodes: &[u32],
        u: &[Vector3<f64>],
        force: &[f64],
        patch: &mut CompliancePatch,
    ) {
        patch.nodes.clear();
        for &n in nodes {
            let s = 3 * n as usize;
            let held =
                (n as usize) >= model.n_nodes() || model.support[s..s + 3].iter().all(|&h| h);
            if !held && !patch.nodes.contains(&n) {
                patch.nodes.push(n);
            }
        }
        let m = patch.nodes.len();
        let m3 = 3 * m;
        let n_dofs = model.pattern.n_dofs;
        patch.shared = None;
        patch.blocks.clear();
        patch.blocks.resize(m3 * m3, 0.0);
        for first in (0..m).step_by(BATCH_NODES) {
            let batch = &patch.nodes[first..(first + BATCH_NODES).min(m)];
            let ncols = 3 * batch.len();
            self.cols.clear();
            self.cols.resize(n_dofs * ncols, 0.0);
            for (k, &n) in batch.iter().enumerate() {
                for a in 0..3 {
                    let d = 3 * n as usize + a;
                    // A roller's held DOF keeps a zero column.
                    if !model.support[d] {
                        self.cols[(3 * k + a) * n_dofs + d] = 1.0;
                    }
                }
            }
            self.factor.solve_many(&mut self.cols, ncols);
            for (k, _) in batch.iter().enumerate() {
                let j = first + k;
                for b in 0..3 {
                    let col = &self.cols[(3 * k + b) * n_dofs..(3 * k + b + 1) * n_dofs];
                    for (i, &ni) in patch.nodes.iter().enumerate() {
                        for a in 0..3 {
                            let d = 3 * ni as usize + a;
                            let v = if model.support[d] { 0.0 } else { col[d] };
                            patch.blocks[(3 * i + a) * m3 + 3 * j + b] = v;
                        }
                    }
                }
            }
        }
        // Symmetric to rounding; made exactly so (the force loop's W is).
        for i in 0..m3 {
            for j in 0..i {
                let v = 0.5 * (patch.blocks[i * m3 + j] + patch.blocks[j * m3 + i]);
                patch.blocks[i * m3 + j] = v;
                patch.blocks[j * m3 + i] = v;
            }
        }
        patch.free_positions.clear();
        for (i, &ni) in patch.nodes.iter().enumerate() {
            let mut x: Point3<f64> = model.rest[ni as usize] + u[ni as usize];
            for (j, &nj) in patch.nodes.iter().enumerate() {
                let c = Matrix3::from_fn(|a, b| patch.blocks[(3 * i + a) * m3 + 3 * j + b]);
                x -= c * node_vec(force, nj as usize);
            }
            patch.free_positions.push(x);
        }
        patch.linear = false;
    }
}
