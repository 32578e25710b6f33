//! Strategy `neo-hookean`: compressible neo-Hookean hyperelasticity,
//! `psi = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2`, solved by Newton's
//! method with a backtracking line search; the accuracy reference.
//!
//! Each Newton iteration assembles the tangent (constrained DOFs eliminated as
//! in `direct`, with the remaining gap to the enforced values as the lift),
//! factors it (same symbolic analysis every time; the rest stiffness is used
//! when the tangent is not positive definite) and steps. Converged when the
//! enforced values are met (to `1e-12` of the largest of them, of their
//! change in the step and of the displacement) and the free residual passes the test of [`IterativeOptions`]
//! (`|r| <= max(tolerance |f|, F_floor)`).
//!
//! Line search: the largest `alpha` in `1, 1/2, 1/4, ...` that keeps every
//! element's `J > 0` and, once the enforced values are met, gives a
//! sufficient decrease. Sufficient decrease is Armijo's on the energy,
//! `W(u + alpha du) <= W(u) + 1e-4 alpha W'(u) du`, while the energy change
//! is resolved; near the solution the decrease `~ |r|^2 / k` falls below
//! the rounding of `W` itself (relative `(|r| / |f|)^2`: 1e-18 at a 1e-9
//! tolerance, far below `f64::EPSILON`), and Armijo's test then accepts or
//! rejects on noise, which stalled the reference at first contact. When
//! `|W(u + alpha du) - W(u)|` is within the rounding bound of the energy
//! (`(16 + elements) eps` times the summed magnitudes of its terms), the
//! step is accepted on a sufficient decrease of the free residual instead,
//! `|r(u + alpha du)| <= (1 - 1e-4 alpha) |r(u)|`, the merit function of
//! Newton's method for the equations `r = 0`.
//!
//! Kinematics in displacement differences (`F = I + H`,
//! [`super::element::TetGeometry::displacement_gradient`]) and a
//! cancellation-free energy ([`super::element::neo_hookean_energy`]): at
//! light load forces and energy keep full relative precision.

use super::assembly::{node_vec, scatter_add};
use super::constraint::{Constraint, Frame, StepRows};
use super::corotational::IterativeOptions;
use super::element::{neo_hookean_element_h, neo_hookean_energy, neo_hookean_forces};
use super::factor::SparseLlt;
use super::model::Model;
use super::tangent::TangentPatch;
use super::ties::TieSprings;
use super::{CompliancePatch, Solution, SolveError};
use nalgebra::{SVector, Vector3};

/// The `neo-hookean` strategy.
#[derive(Debug)]
pub struct NeoHookean {
    model: Model,
    opts: IterativeOptions,
    rows: StepRows,
    frame: Frame,
    factor: SparseLlt,
    values: Vec<f64>,
    rhs: Vec<f64>,
    lift: Vec<f64>,
    u: Vec<f64>,
    trial: Vec<f64>,
    f: Vec<f64>,
    fnode: Vec<f64>,
    ftrial: Vec<f64>,
    good: Vec<f64>,
    solution: Solution,
    support_reactions: Vec<Vector3<f64>>,
    /// Absolute floor of the convergence test, N.
    floor: f64,
    /// The tangent compliance of the last step, for the force loop.
    tangent: TangentPatch,
    /// Internal force at the last good state (the patch's), N.
    f_good: Vec<f64>,
    /// The intact ties, as springs of the energy.
    springs: TieSprings,
}

/// Sufficient-decrease constant of the line search (Armijo's `c1`).
const ARMIJO: f64 = 1e-4;

/// The energy and the rounding bound of its evaluation, J.
#[derive(Debug, Clone, Copy)]
struct Energy {
    value: f64,
    rounding: f64,
}

/// Corner displacements of element `t`.
fn corner_u(t: &[u32; 4], u: &[f64]) -> [Vector3<f64>; 4] {
    t.map(|n| node_vec(u, n as usize))
}

impl NeoHookean {
    /// Builds the strategy (symbolic analysis of the pattern).
    pub fn new(model: Model, opts: IterativeOptions) -> Result<Self, SolveError> {
        if model.pressure.is_some() {
            return Err(SolveError::InvalidModel(
                "the nodal-pressure element is linear: strategy neo-hookean takes tet4".into(),
            ));
        }
        let n = model.pattern.n_dofs;
        Ok(Self {
            tangent: TangentPatch::new(&model)?,
            f_good: vec![0.0; n],
            springs: TieSprings::default(),
            factor: SparseLlt::new(&model.pattern)?,
            rows: StepRows::new(model.n_nodes()),
            frame: Frame::new(model.support.clone()),
            values: vec![0.0; model.pattern.nnz()],
            rhs: vec![0.0; n],
            lift: vec![0.0; n],
            u: vec![0.0; n],
            trial: vec![0.0; n],
            f: vec![0.0; n],
            fnode: vec![0.0; n],
            ftrial: vec![0.0; n],
            good: vec![0.0; n],
            solution: Solution {
                displacements: vec![Vector3::zeros(); model.n_nodes()],
                ..Default::default()
            },
            support_reactions: Vec::new(),
            floor: model.force_floor(opts.floor_strain),
            opts,
            model,
        })
    }

    /// Total strain energy (J) at displacement `u` and the bound of its
    /// rounding, or the first inverted element.
    fn energy(m: &Model, springs: &TieSprings, u: &[f64]) -> Result<Energy, SolveError> {
        // The springs' energy is a sum of non-negative terms: its own
        // magnitude.
        let ws = springs.energy(&m.rest, u);
        let (mut w, mut mag) = (ws, ws);
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
            match neo_hookean_energy(&h, m.lame_pa[e][0], m.lame_pa[e][1]) {
                Some(psi) => {
                    w += m.geoms[e].volume * psi.value;
                    mag += m.geoms[e].volume * psi.magnitude;
                }
                None => return Err(inverted(e, &h)),
            }
        }
        let rounding = (16.0 + m.tets.len() as f64) * f64::EPSILON * mag;
        Ok(Energy { value: w, rounding })
    }

    /// Norm of the free-DOF internal force (N, in node bases) at `u`.
    fn free_residual(&mut self, u: &[f64]) -> Result<f64, SolveError> {
        let m = &self.model;
        self.ftrial.fill(0.0);
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
            let forces = neo_hookean_forces(&m.geoms[e], &h, m.lame_pa[e][0], m.lame_pa[e][1])
                .ok_or_else(|| inverted(e, &h))?;
            for a in 0..4 {
                let n = 3 * t[a] as usize;
                for i in 0..3 {
                    self.ftrial[n + i] += forces[a][i];
                }
            }
        }
        self.springs.add_forces(&m.rest, u, &mut self.ftrial);
        self.frame.to_node_basis(&mut self.ftrial);
        Ok(self.free_norm(&self.ftrial))
    }

    /// Norm over the free DOFs (node bases) of a node-basis vector.
    fn free_norm(&self, v: &[f64]) -> f64 {
        v.iter()
            .zip(&self.frame.fixed)
            .filter(|(_, fixed)| !**fixed)
            .map(|(x, _)| x * x)
            .sum::<f64>()
            .sqrt()
    }

    /// Assembles the internal force (into `f`) and the eliminated tangent
    /// system at `u`. `linear` uses the rest stiffness instead of the tangent.
    fn assemble(&mut self, linear: bool) -> Result<(), SolveError> {
        let m = &self.model;
        self.values.fill(0.0);
        self.rhs.fill(0.0);
        self.f.fill(0.0);
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, &self.u));
            let (forces, mut k) =
                neo_hookean_element_h(&m.geoms[e], &h, m.lame_pa[e][0], m.lame_pa[e][1])
                    .ok_or_else(|| inverted(e, &h))?;
            let mut fe = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                fe.fixed_rows_mut::<3>(3 * a).copy_from(&forces[a]);
            }
            scatter_add(t, &fe, &mut self.f);
            if linear {
                k = m.kel[e];
            }
            self.frame.rotate_element(t, &mut k);
            self.frame.scatter(
                &m.pattern,
                e,
                t,
                &k,
                &self.lift,
                &mut self.values,
                &mut self.rhs,
            );
        }
        self.springs.add_forces(&m.rest, &self.u, &mut self.f);
        for (i, t, mut k) in self.springs.elements(&m.rest, &self.u) {
            self.frame.rotate_element(&t, &mut k);
            self.frame.scatter(
                &m.pattern,
                m.tets.len() + i,
                &t,
                &k,
                &self.lift,
                &mut self.values,
                &mut self.rhs,
            );
        }
        self.fnode.copy_from_slice(&self.f);
        self.frame.to_node_basis(&mut self.fnode);
        for d in 0..self.rhs.len() {
            if !self.frame.fixed[d] {
                self.rhs[d] -= self.fnode[d];
            }
        }
        self.frame
            .finish(&m.pattern, &self.lift, &mut self.values, &mut self.rhs);
        Ok(())
    }

    fn iterate(&mut self) -> Result<u32, SolveError> {
        self.u.copy_from_slice(&self.good);
        // The inversion that last shortened a step toward the enforced values.
        let mut blocking: Option<SolveError> = None;
        // The gap at the start of the step (m), the scale of its tolerance.
        let mut gap0 = 0.0f64;
        for it in 1..=self.opts.max_outer {
            // Remaining gap to the enforced values, in node bases.
            self.trial.copy_from_slice(&self.u);
            self.frame.to_node_basis(&mut self.trial);
            let mut gap = 0.0f64;
            for d in 0..self.lift.len() {
                self.lift[d] = if self.frame.fixed[d] {
                    self.frame.value[d] - self.trial[d]
                } else {
                    0.0
                };
                gap = gap.max(self.lift[d].abs());
            }
            if it == 1 {
                gap0 = gap;
            }
            self.assemble(false)?;
            let res = self.free_norm(&self.fnode);
            let total = self.f.iter().map(|v| v * v).sum::<f64>().sqrt();
            let scale = self.frame.value.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            if !(res.is_finite() && total.is_finite()) {
                return Err(SolveError::NonFinite("neo-Hookean residual".into()));
            }
            // Met to 1e-12 of the largest of the enforced values, of the
            // step's change of them and of the displacement: relative, so
            // that a 1e-18 m push from rest is applied, and not relative to
            // the enforced values alone, so that a return to zero (where
            // `u_c - 0` keeps a rounding residue of the previous values) and
            // node bases (rounding of `B^T u`) terminate.
            let umax = self.u.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let met = gap <= 1e-12 * scale.max(gap0).max(umax);
            if met && res <= self.opts.threshold(total, self.floor) {
                return Ok(it);
            }
            if it == self.opts.max_outer {
                if !met {
                    if let Some(e) = blocking {
                        return Err(e);
                    }
                }
                return Err(SolveError::NotConverged {
                    iterations: it,
                    residual: self.opts.relative_residual(res, total, self.floor),
                });
            }
            if self
                .factor
                .factorize(&self.model.pattern, &self.values)
                .is_err()
            {
                self.assemble(true)?;
                self.factor.factorize(&self.model.pattern, &self.values)?;
            }
            self.factor.solve(&mut self.rhs);
            self.frame.to_global_basis(&mut self.rhs);
            // Line search (module documentation). While the enforced
            // values are not met, any step that inverts nothing is taken.
            let w0 = if met {
                Some(Self::energy(&self.model, &self.springs, &self.u)?)
            } else {
                None
            };
            let slope: f64 = self.f.iter().zip(&self.rhs).map(|(a, b)| a * b).sum();
            let mut alpha = 1.0;
            let mut last_err = None;
            let mut accepted = false;
            for _ in 0..40 {
                for i in 0..self.u.len() {
                    self.trial[i] = self.u[i] + alpha * self.rhs[i];
                }
                match Self::energy(&self.model, &self.springs, &self.trial) {
                    Ok(w) => {
                        accepted = match w0 {
                            None => true,
                            Some(w0) => {
                                let dw = w.value - w0.value;
                                if dw <= ARMIJO * alpha * slope {
                                    true
                                } else if dw.abs() <= w.rounding.max(w0.rounding) {
                                    let trial = std::mem::take(&mut self.trial);
                                    let rt = self.free_residual(&trial);
                                    self.trial = trial;
                                    rt? <= (1.0 - ARMIJO * alpha) * res
                                } else {
                                    false
                                }
                            }
                        };
                        if accepted {
                            break;
                        }
                    }
                    Err(e) => last_err = Some(e),
                }
                alpha *= 0.5;
            }
            if !accepted {
                return Err(last_err.unwrap_or(SolveError::NotConverged {
                    iterations: it,
                    residual: self.opts.relative_residual(res, total, self.floor),
                }));
            }
            if !met && alpha < 1.0 {
                // Enforced values that cannot be reached without inverting
                // an element: stop once the steps become negligible.
                if alpha < 1e-6 {
                    return Err(last_err.unwrap_or(SolveError::NotConverged {
                        iterations: it,
                        residual: gap,
                    }));
                }
                blocking = last_err;
            }
            std::mem::swap(&mut self.u, &mut self.trial);
        }
        unreachable!("the loop returns at max_outer")
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.tangent.invalidate();
        self.rows.set(cons, &self.model.support)?;
        self.frame.set(&self.rows);
        let iterations = if self.rows.rows.is_empty() && self.springs.pairs.is_empty() {
            // Nothing enforced: the rest state is the equilibrium (and no
            // warm start survives).
            self.u.fill(0.0);
            self.f.fill(0.0);
            1
        } else {
            let it = self.iterate()?;
            if !self.u.iter().all(|v| v.is_finite()) {
                return Err(SolveError::NonFinite("neo-Hookean displacement".into()));
            }
            it
        };
        self.good.copy_from_slice(&self.u);
        for (i, d) in self.solution.displacements.iter_mut().enumerate() {
            *d = node_vec(&self.u, i);
        }
        self.rows
            .reactions_from_forces(&self.f, &mut self.solution.reactions);
        self.support_reactions.clear();
        self.support_reactions.extend(
            self.model
                .fixed
                .iter()
                .map(|&n| node_vec(&self.f, n as usize)),
        );
        self.solution.iterations = iterations;
        Ok(&self.solution)
    }
}

/// The inversion error of element `e` with displacement gradient `h`.
fn inverted(element: usize, h: &nalgebra::Matrix3<f64>) -> SolveError {
    SolveError::Inverted {
        element,
        jacobian: 1.0 + super::element::det_minus_one(h),
    }
}

impl NeoHookean {
    /// The force loop's patch: the tangent compliance at the last good
    /// state ([`super::tangent`]); `false` when its factorization fails.
    fn tangent_patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) -> bool {
        let (m, u, f) = (&self.model, &self.good, &mut self.f_good);
        if !self.tangent.is_fresh() {
            f.fill(0.0);
            self.springs.add_forces(&m.rest, u, f);
        }
        let refactored = self.tangent.refactor(
            m,
            |e| {
                let t = &m.tets[e];
                let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
                let (forces, k) =
                    neo_hookean_element_h(&m.geoms[e], &h, m.lame_pa[e][0], m.lame_pa[e][1])?;
                let mut fe = SVector::<f64, 12>::zeros();
                for a in 0..4 {
                    fe.fixed_rows_mut::<3>(3 * a).copy_from(&forces[a]);
                }
                scatter_add(t, &fe, f);
                Some(k)
            },
            &self.springs,
            u,
        );
        if refactored.is_err() {
            return false;
        }
        self.tangent.fill(
            &self.model,
            nodes,
            &self.solution.displacements,
            &self.f_good,
            patch,
        );
        true
    }
}

/// The `neo-hookean` strategy ([`super::StrategyKind`]).
pub const KIND: super::StrategyKind = super::StrategyKind {
    name: "neo-hookean",
    label: "neoh",
    linear: false,
    material_model: "neo-hookean",
    build: |model, options| Ok(Box::new(NeoHookean::new(model, options.iterative)?)),
};

stepping_solver!(
    NeoHookean,
    KIND.name,
    [model]
    fn compliance_patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) -> bool {
        self.tangent_patch(nodes, patch)
    }

    fn set_tie_springs(&mut self, springs: &TieSprings) -> bool {
        if self.springs != *springs {
            self.springs.clone_from(springs);
            self.tangent.invalidate();
        }
        true
    }
);
