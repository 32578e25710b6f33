//! Strategy `neo-hookean`: compressible neo-Hookean hyperelasticity,
//! `psi = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2`, solved by Newton's
//! method with a backtracking line search; the accuracy reference.
//!
//! Each Newton iteration assembles the tangent (constrained DOFs eliminated as
//! in `direct`, with the remaining gap to the enforced values as the lift),
//! factors it (same symbolic analysis every time; the rest stiffness is used
//! when the tangent is not positive definite) and steps. The line search
//! takes the largest `alpha` in `1, 1/2, 1/4, ...` that keeps every element's
//! `J > 0` and, once the enforced values are met, decreases the energy
//! (Armijo). Converged when the free residual is below
//! `tolerance x |internal force|` and the enforced values are met.

use super::assembly::{node_vec, scatter_add};
use super::constraint::{Constraint, Frame, StepRows};
use super::corotational::IterativeOptions;
use super::element::{neo_hookean_density, neo_hookean_element};
use super::factor::SparseLlt;
use super::model::Model;
use super::{DeformationSolver, LocalModel, Prescribed, Solution, SolveError};
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
    good: Vec<f64>,
    solution: Solution,
    support_reactions: Vec<Vector3<f64>>,
}

impl NeoHookean {
    /// Builds the strategy (symbolic analysis of the pattern).
    pub fn new(model: Model, opts: IterativeOptions) -> Result<Self, SolveError> {
        let n = model.pattern.n_dofs;
        Ok(Self {
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
            good: vec![0.0; n],
            solution: Solution {
                displacements: vec![Vector3::zeros(); model.n_nodes()],
                ..Default::default()
            },
            support_reactions: Vec::new(),
            opts,
            model,
        })
    }

    /// Total strain energy (J) at displacement `u`, or the first inverted element.
    fn energy(m: &Model, u: &[f64]) -> Result<f64, SolveError> {
        let mut w = 0.0;
        for (e, t) in m.tets.iter().enumerate() {
            let x = t.map(|n| m.rest[n as usize].coords + node_vec(u, n as usize));
            let f = m.geoms[e].deformation_gradient(&x);
            match neo_hookean_density(&f, m.lambda, m.mu) {
                Some(psi) => w += m.geoms[e].volume * psi,
                None => {
                    return Err(SolveError::Inverted {
                        element: e,
                        jacobian: f.determinant(),
                    });
                }
            }
        }
        Ok(w)
    }

    /// Assembles the internal force (into `f`) and the eliminated tangent
    /// system at `u`. `linear` uses the rest stiffness instead of the tangent.
    fn assemble(&mut self, linear: bool) -> Result<(), SolveError> {
        let m = &self.model;
        self.values.fill(0.0);
        self.rhs.fill(0.0);
        self.f.fill(0.0);
        for (e, t) in m.tets.iter().enumerate() {
            let x = t.map(|n| m.rest[n as usize].coords + node_vec(&self.u, n as usize));
            let fdef = m.geoms[e].deformation_gradient(&x);
            let (forces, mut k) = neo_hookean_element(&m.geoms[e], &fdef, m.lambda, m.mu).ok_or(
                SolveError::Inverted {
                    element: e,
                    jacobian: fdef.determinant(),
                },
            )?;
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
            self.assemble(false)?;
            let res = (0..self.rhs.len())
                .filter(|&d| !self.frame.fixed[d])
                .map(|d| self.fnode[d] * self.fnode[d])
                .sum::<f64>()
                .sqrt();
            let total = self.f.iter().map(|v| v * v).sum::<f64>().sqrt();
            let scale = self.frame.value.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            if !res.is_finite() {
                return Err(SolveError::NonFinite("neo-Hookean residual".into()));
            }
            if gap <= 1e-12 * scale && (res <= self.opts.tolerance * total || res == 0.0) {
                return Ok(it);
            }
            if it == self.opts.max_outer {
                if gap > 0.0 {
                    if let Some(e) = blocking {
                        return Err(e);
                    }
                }
                return Err(SolveError::NotConverged {
                    iterations: it,
                    residual: res / total.max(f64::MIN_POSITIVE),
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
            // Line search.
            let w0 = if gap == 0.0 {
                Self::energy(&self.model, &self.u)?
            } else {
                0.0
            };
            let slope: f64 = self.f.iter().zip(&self.rhs).map(|(a, b)| a * b).sum();
            let mut alpha = 1.0;
            let mut last_err = None;
            let mut accepted = false;
            for _ in 0..40 {
                for i in 0..self.u.len() {
                    self.trial[i] = self.u[i] + alpha * self.rhs[i];
                }
                match Self::energy(&self.model, &self.trial) {
                    Ok(w) => {
                        let ok = gap > 0.0 || w <= w0 + 1e-4 * alpha * slope + 1e-13 * w0.abs();
                        if ok {
                            accepted = true;
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
                    residual: res / total.max(f64::MIN_POSITIVE),
                }));
            }
            if gap > 0.0 && alpha < 1.0 {
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
        self.rows.set(cons, &self.model.support)?;
        self.frame.set(&self.rows);
        let iterations = if self.rows.rows.is_empty() {
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

impl DeformationSolver for NeoHookean {
    fn name(&self) -> &'static str {
        "neo-hookean"
    }

    fn solve(&mut self, prescribed: &[Prescribed]) -> Result<&Solution, SolveError> {
        self.step(prescribed)
    }

    fn solve_constraints(&mut self, constraints: &[Constraint]) -> Result<&Solution, SolveError> {
        self.step(constraints)
    }

    fn local_model(&self) -> Option<&LocalModel> {
        None
    }

    fn support_reactions(&self) -> &[Vector3<f64>] {
        &self.support_reactions
    }

    fn last_solution(&self) -> Option<&Solution> {
        Some(&self.solution)
    }
}
