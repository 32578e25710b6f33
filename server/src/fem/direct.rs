//! Strategy `direct`: eliminate the constrained DOFs and factor, every step.
//! The exact reference for linear elasticity.
//!
//! Elimination keeps the sparsity pattern: a constrained DOF keeps only its
//! diagonal (`k_dd x_d = k_dd g_d`) and its coupling moves to the right-hand
//! side (`-K_fc g_c`), so the symbolic factorization is computed once and
//! each step is a numeric re-assembly, one numeric factorization and one
//! solve. Normal-only constraints rotate the node's DOFs into a basis whose
//! first axis is the normal (`K' = T^T K T`, element by element).

use super::constraint::{Constraint, Frame, StepRows};
use super::factor::SparseLlt;
use super::model::Model;
use super::{Solution, SolveError};
use nalgebra::Vector3;

/// The `direct` strategy.
#[derive(Debug)]
pub struct Direct {
    model: Model,
    rows: StepRows,
    frame: Frame,
    values: Vec<f64>,
    rhs: Vec<f64>,
    ku: Vec<f64>,
    /// Rotated star weights of the nodal-pressure scatter.
    star: Vec<Vector3<f64>>,
    factor: SparseLlt,
    solution: Solution,
    support_reactions: Vec<Vector3<f64>>,
}

impl Direct {
    /// Builds the strategy (symbolic analysis of the pattern).
    pub fn new(model: Model) -> Result<Self, SolveError> {
        let n_dofs = model.pattern.n_dofs;
        let factor = SparseLlt::new(&model.pattern)?;
        Ok(Self {
            rows: StepRows::new(model.n_nodes()),
            frame: Frame::new(model.support.clone()),
            values: vec![0.0; model.pattern.nnz()],
            rhs: vec![0.0; n_dofs],
            ku: vec![0.0; n_dofs],
            star: Vec::new(),
            factor,
            solution: Solution {
                displacements: vec![Vector3::zeros(); model.n_nodes()],
                ..Default::default()
            },
            support_reactions: Vec::new(),
            model,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.step_loaded(cons, &[])
    }

    /// Adds nodal loads (N, global basis) to the assembled right-hand side
    /// at the free DOFs, in the node bases of the current frame.
    fn add_loads(&mut self, loads: &[(u32, Vector3<f64>)]) {
        if loads.is_empty() {
            return;
        }
        let n = self.rhs.len();
        let mut f = std::mem::take(&mut self.ku);
        f.clear();
        f.resize(n, 0.0);
        for &(node, load) in loads {
            for a in 0..3 {
                f[3 * node as usize + a] += load[a];
            }
        }
        self.frame.to_node_basis(&mut f);
        for (d, v) in f.iter().enumerate() {
            if !self.frame.fixed[d] {
                self.rhs[d] += v;
            }
        }
        self.ku = f;
    }

    /// Reactions of the rows from `K u` minus the applied loads.
    fn reactions_with_loads(&mut self, loads: &[(u32, Vector3<f64>)]) {
        let m = &self.model;
        m.matvec(&self.rhs, &mut self.ku);
        for &(node, load) in loads {
            for a in 0..3 {
                self.ku[3 * node as usize + a] -= load[a];
            }
        }
        self.rows
            .reactions_from_forces(&self.ku, &mut self.solution.reactions);
    }

    fn step_loaded<C: Into<Constraint> + Copy>(
        &mut self,
        cons: &[C],
        loads: &[(u32, Vector3<f64>)],
    ) -> Result<&Solution, SolveError> {
        self.rows.set(cons, &self.model.support)?;
        self.frame.set(&self.rows);
        let m = &self.model;
        self.values.fill(0.0);
        self.rhs.fill(0.0);
        let any_rotated = self
            .rows
            .nodes
            .iter()
            .any(|&n| self.frame.rotated[n as usize]);
        for (e, t) in m.tets.iter().enumerate() {
            let mut k = m.kel[e];
            if any_rotated {
                self.frame.rotate_element(t, &mut k);
            }
            self.frame.scatter(
                &m.pattern,
                e,
                t,
                &k,
                &self.frame.value,
                &mut self.values,
                &mut self.rhs,
            );
        }
        if let Some(p) = &m.pressure {
            p.scatter(
                &self.frame,
                &m.pattern,
                &self.frame.value,
                &mut self.values,
                &mut self.rhs,
                &mut self.star,
            );
        }
        self.frame.finish(
            &m.pattern,
            &self.frame.value,
            &mut self.values,
            &mut self.rhs,
        );
        self.add_loads(loads);
        self.factor.factorize(&self.model.pattern, &self.values)?;
        self.factor.solve(&mut self.rhs);
        self.frame.to_global_basis(&mut self.rhs);
        if !self.rhs.iter().all(|v| v.is_finite()) {
            return Err(SolveError::NonFinite("displacement solution".into()));
        }
        for (i, d) in self.solution.displacements.iter_mut().enumerate() {
            *d = Vector3::new(self.rhs[3 * i], self.rhs[3 * i + 1], self.rhs[3 * i + 2]);
        }
        self.reactions_with_loads(loads);
        let m = &self.model;
        self.support_reactions.clear();
        for &n in &m.fixed {
            let n = 3 * n as usize;
            self.support_reactions
                .push(Vector3::new(self.ku[n], self.ku[n + 1], self.ku[n + 2]));
        }
        self.solution.iterations = 1;
        Ok(&self.solution)
    }
}

/// The `direct` strategy ([`super::StrategyKind`]).
pub const KIND: super::StrategyKind = super::StrategyKind {
    name: "direct",
    label: "lin-direct",
    linear: true,
    material_model: "linear",
    build: |model, _| Ok(Box::new(Direct::new(model)?)),
};

stepping_solver!(
    Direct,
    KIND.name,
    [model]
    fn takes_loads(&self) -> bool {
        true
    }

    fn solve_loaded(
        &mut self,
        constraints: &[Constraint],
        loads: &[(u32, Vector3<f64>)],
    ) -> Result<&Solution, SolveError> {
        self.step_loaded(constraints, loads)
    }

    fn load_response(
        &mut self,
        loads: &[(u32, Vector3<f64>)],
        u: &mut Vec<Vector3<f64>>,
        reactions: &mut Vec<Vector3<f64>>,
    ) -> bool {
        // The homogeneous problem of the last factorization.
        self.rhs.fill(0.0);
        self.add_loads(loads);
        self.factor.solve(&mut self.rhs);
        self.frame.to_global_basis(&mut self.rhs);
        u.clear();
        u.extend(
            self.rhs
                .chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2])),
        );
        let kept = std::mem::take(&mut self.solution.reactions);
        self.reactions_with_loads(loads);
        reactions.clear();
        reactions.extend_from_slice(&self.solution.reactions);
        self.solution.reactions = kept;
        true
    }
);
