//! Strategy `neo-hookean`: compressible neo-Hookean hyperelasticity,
//! `psi = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2`, solved by Newton's
//! method with a backtracking line search; the accuracy reference.
//!
//! Each Newton iteration assembles the tangent (constrained DOFs eliminated as
//! in `direct`, with the remaining gap to the enforced values as the lift)
//! and solves for the step. The numeric factorization is most of a step's
//! cost (on the 48k phantom with the nodal-pressure element, whose two-ring
//! pattern makes the factor dense), so an earlier factor is reused: the
//! step is solved by conjugate gradients on the current tangent,
//! preconditioned by the last factor made (the Newton iterations' own or,
//! when newer, the tangent patch's at the last step's equilibrium), to
//! `1e-6` of the right-hand side. The Newton steps are then the same to that tolerance and the
//! converged answer the same to the solver's. The tangent is factored
//! afresh (same symbolic analysis every time; the rest stiffness used when
//! the tangent is not positive definite) when the iteration fails to
//! converge in [`CG_MAX`] iterations or meets non-positive curvature, and
//! at the next iteration after one that took more than half of them.
//! Converged when the
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
//! The energy is the tissue's plus, when the model has them, the springs of
//! an elastic foundation (`1/2 u^T K_f u` about the rest shape,
//! [`super::foundation::FoundationSprings`]) and of the ties
//! ([`TieSprings`]); they add to the internal force, the tangent (through
//! the element path of the assembly) and the line search's energy. With the
//! average-nodal-pressure element the elements carry the deviatoric
//! neo-Hookean energy (`lambda = -2 mu / 3`) and the nodes the volumetric
//! one, `V_a kappa_a / 2 (ln J_a)^2` with the nodal volume ratio `J_a`
//! ([`NodalVolumes`]); the line search then keeps every `J_a > 0` too.
//! The rest-stiffness fallback is the linear model of the same terms
//! (`model.kel`, which holds the foundation's springs, plus the linear
//! element's `K_vol`).
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
use super::nodal_pressure::{Eliminated, NodalVolumes};
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
    /// The nodal volumetric part's state, with the nodal-pressure element
    /// (empty without).
    nodal: NodalVolumes,
    /// Workspace of the nodal scatters.
    scratch: Vec<Vector3<f64>>,
    /// Whether `factor` holds a factorization (of an earlier iteration's
    /// tangent, the preconditioner of [`Self::solve_preconditioned`]).
    factored: bool,
    /// Whether the next iteration factors afresh: the last preconditioned
    /// solve was slow, the factor too far from the tangent.
    stale: bool,
    /// Whether the tangent patch's factor (at the last step's equilibrium)
    /// is newer than `factor`, and so the preconditioner.
    precondition_patch: bool,
    /// The state (DOF vector, m) the tangent patch was last factored at.
    patch_state: Vec<f64>,
    /// Whether an earlier factor may precondition a Newton step (`false`:
    /// a factorization every iteration, the plain Newton method).
    reuse_factor: bool,
    /// Numeric factorizations of the Newton iterations so far.
    factorizations: u64,
    /// Workspaces of the preconditioned conjugate gradients.
    cg: Cg,
}

/// Workspaces of [`NeoHookean::solve_preconditioned`] (DOF vectors).
#[derive(Debug, Default)]
struct Cg {
    x: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

/// Most conjugate-gradient iterations on an earlier factor before the
/// tangent is factored afresh.
const CG_MAX: u32 = 40;

/// Relative residual of a preconditioned Newton step, `|K du - b| <=
/// CG_RELATIVE |b|`: the step's error then adds `CG_RELATIVE` of the
/// residual to the next one, below the quadratic term of Newton's method
/// until the residual is that small relative to the load, and below the
/// convergence test's tolerances after. Relative only: an absolute target
/// (the test's floor) would leave the free DOFs unmoved under a push of
/// 1e-18 m, whose forces lie below the floor, and the reactions wrong.
const CG_RELATIVE: f64 = 1e-6;

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

/// Lamé parameters `(lambda, mu)` (Pa) of element `e`'s own energy: its
/// material's, or with the nodal-pressure element the deviatoric part alone
/// (`lambda = -2 mu / 3`, the volumetric part on the nodes).
fn element_lame(m: &Model, e: usize) -> (f64, f64) {
    let [lambda, mu] = m.lame_pa[e];
    if m.pressure.is_some() {
        (-2.0 * mu / 3.0, mu)
    } else {
        (lambda, mu)
    }
}

/// Evaluates the nodal volumetric part at `u` when the model has the
/// nodal-pressure element (nothing otherwise).
fn evaluate_nodal(m: &Model, nodal: &mut NodalVolumes, u: &[f64]) -> Result<(), SolveError> {
    if let Some(p) = &m.pressure {
        nodal.evaluate(p, &m.tets, &m.geoms, u)?;
    }
    Ok(())
}

impl NeoHookean {
    /// Builds the strategy (symbolic analysis of the pattern).
    pub fn new(model: Model, opts: IterativeOptions) -> Result<Self, SolveError> {
        let n = model.pattern.n_dofs;
        Ok(Self {
            nodal: model
                .pressure
                .as_ref()
                .map_or_else(NodalVolumes::default, |p| {
                    NodalVolumes::new(p, model.tets.len())
                }),
            scratch: Vec::new(),
            factored: false,
            stale: false,
            precondition_patch: false,
            patch_state: Vec::new(),
            reuse_factor: true,
            factorizations: 0,
            cg: Cg {
                x: vec![0.0; n],
                r: vec![0.0; n],
                z: vec![0.0; n],
                p: vec![0.0; n],
                q: vec![0.0; n],
            },
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
    /// rounding, or the first inverted element (or node, with the
    /// nodal-pressure element).
    fn energy(
        m: &Model,
        springs: &TieSprings,
        nodal: &mut NodalVolumes,
        u: &[f64],
    ) -> Result<Energy, SolveError> {
        // The springs' energies (ties, foundation, the nodal volumetric
        // part) are sums of non-negative terms: their own magnitudes.
        let mut ws = springs.energy(&m.rest, u) + m.foundation.energy(&m.tets, u);
        evaluate_nodal(m, nodal, u)?;
        if let Some(p) = &m.pressure {
            ws += nodal.energy(p);
        }
        let (mut w, mut mag) = (ws, ws);
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
            let (lambda, mu) = element_lame(m, e);
            match neo_hookean_energy(&h, lambda, mu) {
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

    /// Internal force (N, DOF vector, global basis) at `u` into `f`: the
    /// tissue's, the nodal volumetric part's, the foundation's and the
    /// ties'.
    fn internal_force(
        m: &Model,
        springs: &TieSprings,
        nodal: &mut NodalVolumes,
        u: &[f64],
        f: &mut [f64],
    ) -> Result<(), SolveError> {
        f.fill(0.0);
        evaluate_nodal(m, nodal, u)?;
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
            let (lambda, mu) = element_lame(m, e);
            let forces =
                neo_hookean_forces(&m.geoms[e], &h, lambda, mu).ok_or_else(|| inverted(e, &h))?;
            for a in 0..4 {
                let n = 3 * t[a] as usize;
                for i in 0..3 {
                    f[n + i] += forces[a][i];
                }
            }
        }
        if m.pressure.is_some() {
            nodal.add_forces(&m.tets, f);
        }
        m.foundation.add_product(&m.tets, u, f);
        springs.add_forces(&m.rest, u, f);
        Ok(())
    }

    /// Norm of the free-DOF internal force (N, in node bases) at `u`.
    fn free_residual(&mut self, u: &[f64]) -> Result<f64, SolveError> {
        Self::internal_force(
            &self.model,
            &self.springs,
            &mut self.nodal,
            u,
            &mut self.ftrial,
        )?;
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
    /// system at `u`. `linear` uses the rest stiffness instead of the
    /// tangent (`kel`, which holds the foundation's springs, and the linear
    /// nodal part `K_vol`).
    fn assemble(&mut self, linear: bool) -> Result<(), SolveError> {
        let m = &self.model;
        self.values.fill(0.0);
        self.rhs.fill(0.0);
        self.f.fill(0.0);
        evaluate_nodal(m, &mut self.nodal, &self.u)?;
        for (e, t) in m.tets.iter().enumerate() {
            let h = m.geoms[e].displacement_gradient(&corner_u(t, &self.u));
            let (lambda, mu) = element_lame(m, e);
            let (mut forces, mut k) = neo_hookean_element_h(&m.geoms[e], &h, lambda, mu)
                .ok_or_else(|| inverted(e, &h))?;
            if m.pressure.is_some() {
                let fp = self.nodal.element_forces(e, t);
                for a in 0..4 {
                    forces[a] += fp[a];
                }
                self.nodal.add_element_tangent(e, t, &m.geoms[e], &mut k);
            }
            let mut fe = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                fe.fixed_rows_mut::<3>(3 * a).copy_from(&forces[a]);
            }
            scatter_add(t, &fe, &mut self.f);
            if linear {
                k = m.kel[e];
            } else if let Some(kf) = m.foundation.matrix_of(e) {
                // The foundation's springs (in `kel` already).
                k += kf;
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
        m.foundation.add_product(&m.tets, &self.u, &mut self.f);
        if let Some(p) = &m.pressure {
            let out = Eliminated {
                frame: &self.frame,
                pattern: &m.pattern,
                lift: &self.lift,
                values: &mut self.values,
                rhs: &mut self.rhs,
            };
            if linear {
                p.scatter_into(out, &mut self.scratch);
            } else {
                self.nodal.scatter(p, out, &mut self.scratch);
            }
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
            // The step: by conjugate gradients on an earlier factor while
            // that converges quickly, else from a fresh factor.
            let reused = self.reuse_factor && !self.stale && {
                match self.solve_preconditioned() {
                    Some(k) => {
                        self.stale = k > CG_MAX / 2;
                        true
                    }
                    None => false,
                }
            };
            if !reused {
                self.factored = false;
                self.factorizations += 1;
                if self
                    .factor
                    .factorize(&self.model.pattern, &self.values)
                    .is_err()
                {
                    self.assemble(true)?;
                    self.factor.factorize(&self.model.pattern, &self.values)?;
                }
                self.factored = true;
                self.stale = false;
                self.precondition_patch = false;
                self.factor.solve(&mut self.rhs);
            }
            self.frame.to_global_basis(&mut self.rhs);
            // Line search (module documentation). While the enforced
            // values are not met, any step that inverts nothing is taken.
            let w0 = if met {
                Some(Self::energy(
                    &self.model,
                    &self.springs,
                    &mut self.nodal,
                    &self.u,
                )?)
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
                match Self::energy(&self.model, &self.springs, &mut self.nodal, &self.trial) {
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

    /// Solves the eliminated system (`values`, `rhs`) into `rhs` by
    /// conjugate gradients preconditioned with the held factor of an
    /// earlier tangent, to `|K du - b| <= CG_RELATIVE |b|` (N)
    /// over the free DOFs; the constrained DOFs take their lift (their
    /// rows are `diag x = diag g`, decoupled). The iteration runs on the
    /// free DOFs alone: the factor's inverse restricted to them is
    /// symmetric positive definite whichever DOFs it had constrained, so
    /// the method is conjugate gradients on `K_ff` and its answer the same
    /// Newton step to the tolerance. Returns the iterations, or `None`
    /// (`rhs` untouched) after [`CG_MAX`] of them or on a direction of
    /// non-positive curvature (a tangent that is not positive definite,
    /// left to the factorization and its fallback).
    fn solve_preconditioned(&mut self) -> Option<u32> {
        let Self {
            model,
            frame,
            factor,
            values,
            rhs,
            lift,
            cg,
            tangent,
            precondition_patch,
            factored,
            ..
        } = self;
        let factor = match tangent.factor_mut() {
            Some(f) if *precondition_patch => f,
            _ if *factored => factor,
            _ => return None,
        };
        let fixed = &frame.fixed;
        let Cg { x, r, z, p, q } = cg;
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
        let free = |v: &mut [f64]| {
            for (v, &c) in v.iter_mut().zip(fixed) {
                if c {
                    *v = 0.0;
                }
            }
        };
        x.fill(0.0);
        r.copy_from_slice(rhs);
        free(r);
        let norm = dot(r, r).sqrt();
        if !norm.is_finite() {
            return None;
        }
        let goal = CG_RELATIVE * norm;
        let mut iterations = 0;
        if norm > goal {
            z.copy_from_slice(r);
            factor.solve(z);
            free(z);
            p.copy_from_slice(z);
            let mut rz = dot(r, z);
            loop {
                if iterations == CG_MAX {
                    return None;
                }
                iterations += 1;
                model.pattern.sym_matvec(values, p, q);
                let pq = dot(p, q);
                if !(pq > 0.0 && rz > 0.0) {
                    return None;
                }
                let a = rz / pq;
                for i in 0..x.len() {
                    x[i] += a * p[i];
                    r[i] -= a * q[i];
                }
                if dot(r, r).sqrt() <= goal {
                    break;
                }
                z.copy_from_slice(r);
                factor.solve(z);
                free(z);
                let rz_next = dot(r, z);
                let beta = rz_next / rz;
                rz = rz_next;
                for i in 0..p.len() {
                    p[i] = z[i] + beta * p[i];
                }
            }
        }
        for d in 0..rhs.len() {
            rhs[d] = if fixed[d] { lift[d] } else { x[d] };
        }
        Some(iterations)
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.rows.set(cons, &self.model.support)?;
        self.frame.set(&self.rows);
        let iterations = if self.rows.rows.is_empty() && self.springs.pairs.is_empty() {
            // Nothing enforced: the rest state is the equilibrium (and no
            // warm start survives, the preconditioner neither: the next
            // step gives the numbers of a fresh solver).
            self.u.fill(0.0);
            self.f.fill(0.0);
            self.factored = false;
            self.precondition_patch = false;
            self.stale = false;
            1
        } else {
            let it = self.iterate()?;
            if !self.u.iter().all(|v| v.is_finite()) {
                return Err(SolveError::NonFinite("neo-Hookean displacement".into()));
            }
            it
        };
        self.good.copy_from_slice(&self.u);
        // The patch's factor is a function of the state (and the ties'
        // springs, which invalidate it themselves): kept while the state
        // stays the same to the bit, as at rest before the first contact.
        let same = self.good.len() == self.patch_state.len()
            && self
                .good
                .iter()
                .zip(&self.patch_state)
                .all(|(a, b)| a.to_bits() == b.to_bits());
        if !same {
            self.tangent.invalidate();
        }
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
        let support = &self.model.support;
        let free = |&n: &u32| {
            let s = 3 * n as usize;
            n < self.model.n_nodes() as u32 && !support[s..s + 3].iter().all(|&h| h)
        };
        if !nodes.iter().any(free) {
            // An empty patch needs no factor (none is made until one is
            // asked for).
            self.tangent.fill(
                &self.model,
                &[],
                &self.solution.displacements,
                &self.f_good,
                patch,
            );
            return true;
        }
        let (m, u, f) = (&self.model, &self.good, &mut self.f_good);
        let nodal = &mut self.nodal;
        if !self.tangent.is_fresh() {
            // The forces of the springs and the nodal part here, the
            // elements' in the assembly below.
            if evaluate_nodal(m, nodal, u).is_err() {
                return false;
            }
            f.fill(0.0);
            if m.pressure.is_some() {
                nodal.add_forces(&m.tets, f);
            }
            m.foundation.add_product(&m.tets, u, f);
            self.springs.add_forces(&m.rest, u, f);
        }
        let nodal = &*nodal;
        let refactoring = !self.tangent.is_fresh();
        let refactored = self.tangent.refactor(
            m,
            |e| {
                let t = &m.tets[e];
                let h = m.geoms[e].displacement_gradient(&corner_u(t, u));
                let (lambda, mu) = element_lame(m, e);
                let (forces, mut k) = neo_hookean_element_h(&m.geoms[e], &h, lambda, mu)?;
                if m.pressure.is_some() {
                    nodal.add_element_tangent(e, t, &m.geoms[e], &mut k);
                }
                let mut fe = SVector::<f64, 12>::zeros();
                for a in 0..4 {
                    fe.fixed_rows_mut::<3>(3 * a).copy_from(&forces[a]);
                }
                scatter_add(t, &fe, f);
                Some(k)
            },
            &self.springs,
            m.pressure.as_ref().map(|p| (p, nodal)),
            u,
        );
        if refactored.is_err() {
            return false;
        }
        if refactoring {
            self.patch_state.clone_from(&self.good);
            // The next step's Newton iterations start near this state.
            self.precondition_patch = true;
            self.stale = false;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::foundation::{Foundation, fold_into, outer_faces_where};
    use crate::fem::{Element, Material, Prescribed, SolverOptions, Strategy, build_solver};
    use crate::mesh::TetMesh;
    use crate::mesh::blocks::cube;
    use nalgebra::{Matrix3, Point3, Rotation3};

    const L: f64 = 0.01;

    /// A 10 mm cube of 2 x 2 x 2 cells with every node moved at random by up
    /// to 0.5 mm along each axis (a tenth of a cell), so that no element is
    /// a regular one.
    fn perturbed_cube(seed: u64) -> TetMesh {
        let mut mesh = cube(L, 2);
        let mut r = crate::test_rng::unit(seed);
        for p in &mut mesh.nodes {
            for i in 0..3 {
                p[i] += (r() - 0.5) * 1e-3;
            }
        }
        mesh
    }

    /// The neo-Hookean strategy on `mesh` with no support (its energy is
    /// all there is to check), the nodal-pressure element when asked, a
    /// foundation (1e6 Pa/m) on the faces whose centroid lies below 2 mm
    /// and a stretched tie across the cube (0.1 N/m, rest length 90 % of
    /// the distance of its nodes, coupled in the pattern beside the stars).
    fn strategy(mesh: &TetMesh, nu: f64, nodal: bool) -> NeoHookean {
        let material = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: nu,
        };
        let mut model = Model::new(mesh, material, &[], &[]).unwrap();
        if nodal {
            model.use_nodal_pressure();
        }
        let faces = outer_faces_where(mesh, |c| c.z < 0.002);
        assert!(!faces.is_empty());
        fold_into(
            &mut model,
            &Foundation {
                stiffness_pa_per_m: 1e6,
                faces,
            },
        )
        .unwrap();
        let (a, b) = (0, mesh.nodes.len() as u32 - 1);
        model.couple_pairs(&[[a, b]]).unwrap();
        let mut s = NeoHookean::new(model, IterativeOptions::reference()).unwrap();
        s.springs = TieSprings {
            pairs: vec![(
                0,
                crate::fem::ties::TiePair {
                    first_tie: 0,
                    a,
                    b,
                    rest_length_m: 0.9 * (mesh.nodes[b as usize] - mesh.nodes[a as usize]).norm(),
                    stiffness_n_per_m: 0.1,
                },
            )],
        };
        s
    }

    /// A large deformation of `mesh`: a rotation by 0.4 rad, a stretch of
    /// a few percent and a random part of up to 0.2 mm a DOF.
    fn deformation(mesh: &TetMesh, seed: u64) -> Vec<f64> {
        let rot = Rotation3::from_euler_angles(0.4, -0.2, 0.3).into_inner();
        let stretch = Matrix3::new(1.03, 0.01, 0.0, 0.0, 0.98, 0.02, 0.01, 0.0, 1.04);
        let c = Point3::new(L / 2.0, L / 2.0, L / 2.0);
        let mut r = crate::test_rng::unit(seed);
        mesh.nodes
            .iter()
            .flat_map(|p| {
                let x = rot * stretch * (p - c) - (p - c);
                [x.x, x.y, x.z]
            })
            .map(|v| v + (r() - 0.5) * 4e-4)
            .collect()
    }

    fn force(s: &mut NeoHookean, u: &[f64]) -> Vec<f64> {
        let mut f = vec![0.0; u.len()];
        NeoHookean::internal_force(&s.model, &s.springs, &mut s.nodal, u, &mut f).unwrap();
        f
    }

    fn energy(s: &mut NeoHookean, u: &[f64]) -> f64 {
        NeoHookean::energy(&s.model, &s.springs, &mut s.nodal, u)
            .unwrap()
            .value
    }

    /// The internal force is the gradient of the energy (tissue, nodal
    /// part, foundation, tie), checked by central differences of step `h` =
    /// 1e-8 m: their truncation error `h^2 W''' ~ 1e-16 N` and rounding
    /// `eps W / h ~ 1e-13 N` lie far below the bound, 1e-7 of the largest
    /// force (about 1e-3 N here).
    fn check_gradient(nodal: bool) {
        let mesh = perturbed_cube(3);
        let mut s = strategy(&mesh, 0.45, nodal);
        let u = deformation(&mesh, 5);
        let f = force(&mut s, &u);
        let scale = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 1e-4, "{scale}");
        let h = 1e-8;
        let mut x = u.clone();
        for i in 0..u.len() {
            x[i] = u[i] + h;
            let wp = energy(&mut s, &x);
            x[i] = u[i] - h;
            let wm = energy(&mut s, &x);
            x[i] = u[i];
            let num = (wp - wm) / (2.0 * h);
            assert!(
                (num - f[i]).abs() < 1e-7 * scale,
                "DOF {i}: {num:e} vs {:e}",
                f[i]
            );
        }
    }

    #[test]
    fn the_force_is_the_gradient_of_the_energy_with_the_foundation() {
        check_gradient(false);
    }

    #[test]
    fn the_force_is_the_gradient_of_the_energy_with_nodal_pressure() {
        check_gradient(true);
    }

    /// The assembled tangent (elements, the nodal part's rank-one and
    /// volume-Hessian terms, the foundation, the tie) is the derivative of the
    /// internal force: `K v` against `(f(u + h v) - f(u - h v)) / 2h` for
    /// random directions `v` (|v| ~ 1 mm, h = 1e-5: a move of 10 nm,
    /// truncation ~1e-10 relative), to 1e-6 of `|K v|`.
    #[test]
    fn the_tangent_is_the_derivative_of_the_force() {
        for nodal in [false, true] {
            let mesh = perturbed_cube(11);
            let mut s = strategy(&mesh, 0.49, nodal);
            s.u = deformation(&mesh, 13);
            s.assemble(false).unwrap();
            let mut r = crate::test_rng::unit(17);
            for _ in 0..4 {
                let v: Vec<f64> = s.u.iter().map(|_| (r() - 0.5) * 2e-3).collect();
                let mut kv = vec![0.0; v.len()];
                s.model.pattern.sym_matvec(&s.values, &v, &mut kv);
                let h = 1e-5;
                let (up, um): (Vec<f64>, Vec<f64>) =
                    s.u.iter()
                        .zip(&v)
                        .map(|(u, v)| (u + h * v, u - h * v))
                        .unzip();
                let (fp, fm) = (force(&mut s, &up), force(&mut s, &um));
                let scale = kv.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                for i in 0..v.len() {
                    let num = (fp[i] - fm[i]) / (2.0 * h);
                    assert!(
                        (num - kv[i]).abs() < 1e-6 * scale,
                        "nodal {nodal}, DOF {i}: {num:e} vs {:e}",
                        kv[i]
                    );
                }
            }
        }
    }

    /// At rest the tangent is the rest stiffness, the fallback of a
    /// tangent that is not positive definite: `kel` (deviatoric with the
    /// nodal-pressure element, the foundation's springs in it) plus the
    /// linear nodal part `K_vol`, counted once each (and the tie's tangent
    /// in both).
    #[test]
    fn at_rest_the_tangent_is_the_rest_stiffness() {
        for nodal in [false, true] {
            let mesh = perturbed_cube(23);
            let mut s = strategy(&mesh, 0.45, nodal);
            s.assemble(false).unwrap();
            let tangent = s.values.clone();
            s.assemble(true).unwrap();
            let scale = tangent.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in tangent.iter().zip(&s.values) {
                assert!(
                    (a - b).abs() < 1e-10 * scale,
                    "nodal {nodal}: {a:e} vs {b:e}"
                );
            }
        }
    }

    /// The nodes of `mesh` where `f` holds.
    fn nodes_where(mesh: &TetMesh, f: impl Fn(&Point3<f64>) -> bool) -> Vec<u32> {
        (0..mesh.nodes.len() as u32)
            .filter(|&i| f(&mesh.nodes[i as usize]))
            .collect()
    }

    /// The smooth press of a cube of side `l` (bottom fixed, the top held
    /// at `u = (0, 0, -d sin(pi x / l) sin(pi y / l))`, the sides free;
    /// with a foundation of `k` Pa/m on the sides when given) by
    /// `strategy` and `element`: the displacements (m) and the net
    /// vertical force on the top (N).
    fn smooth_press(
        mesh: &TetMesh,
        l: f64,
        d: f64,
        nu: f64,
        strategy: Strategy,
        element: Element,
        k: Option<f64>,
    ) -> (Vec<Vector3<f64>>, f64) {
        let fixed = nodes_where(mesh, |p| p.z < 1e-12);
        let cons = press_rows(mesh, l, d);
        let material = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: nu,
        };
        let opts = SolverOptions {
            element,
            iterative: IterativeOptions::reference(),
            foundation: k.map(|k| Foundation {
                stiffness_pa_per_m: k,
                faces: outer_faces_where(mesh, |c| {
                    c.z > 1e-12 && c.z < l - 1e-12 && c.x.min(c.y).min(l - c.x).min(l - c.y) < 1e-12
                }),
            }),
            ..SolverOptions::default()
        };
        let mut s = build_solver(strategy, mesh, material, &fixed, &opts).unwrap();
        let sol = s.solve(&cons).unwrap();
        (
            sol.displacements.clone(),
            sol.reactions.iter().map(|r| r.z).sum(),
        )
    }

    /// Linearization consistency of the nonlinear nodal-pressure element:
    /// its energy linearizes to the linear element's, so at a strain of
    /// 1e-5 `neo-hookean` meets `compliance` with the same element (alone
    /// and with a foundation on the sides) to O(strain) relative (measured:
    /// 3e-6 at nu = 0.45, 8e-5 at 0.4999, tenfold at a tenfold strain);
    /// the bound 1e-3 leaves a twelvefold margin at least and is
    /// far below the gap between the two elements (tet4 is several times
    /// stiffer at nu = 0.4999) or a wrong bulk modulus on the nodes.
    #[test]
    fn at_small_load_nodal_pressure_meets_the_linear_element() {
        let l = 0.02;
        let mesh = cube(l, 3);
        let d = 2e-7;
        for nu in [0.45, 0.4999] {
            for k in [None, Some(1e5)] {
                let e = Element::Tet4NodalPressure;
                let (lin, f_lin) = smooth_press(&mesh, l, d, nu, Strategy::Compliance, e, k);
                let (u, f) = smooth_press(&mesh, l, d, nu, Strategy::NeoHookean, e, k);
                let scale = lin.iter().fold(0.0f64, |m, u| m.max(u.norm()));
                let du = u
                    .iter()
                    .zip(&lin)
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
                eprintln!(
                    "nu {nu}, k {k:?}: displacement {:.2e}, force {:.2e} relative",
                    du / scale,
                    (f - f_lin).abs() / f_lin.abs()
                );
                assert!(du < 1e-3 * scale, "nu {nu}, k {k:?}: {du:e} of {scale:e}");
                assert!(
                    (f - f_lin).abs() < 1e-3 * f_lin.abs(),
                    "nu {nu}, k {k:?}: {f} N vs {f_lin} N"
                );
            }
        }
    }

    /// The smooth press of [`smooth_press`] on a 3 x 3 x 3 cube with the
    /// nodal-pressure element and a foundation on the sides, as a
    /// `NeoHookean` whose factor reuse is `reuse`.
    fn press_strategy(mesh: &TetMesh, l: f64, reuse: bool) -> NeoHookean {
        let fixed = nodes_where(mesh, |p| p.z < 1e-12);
        let material = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: 0.45,
        };
        let mut model = Model::new(mesh, material, &fixed, &[]).unwrap();
        model.use_nodal_pressure();
        let faces = outer_faces_where(mesh, |c| {
            c.z > 1e-12 && c.z < l - 1e-12 && c.x.min(c.y).min(l - c.x).min(l - c.y) < 1e-12
        });
        fold_into(
            &mut model,
            &Foundation {
                stiffness_pa_per_m: 1e5,
                faces,
            },
        )
        .unwrap();
        let mut s = NeoHookean::new(model, IterativeOptions::reference()).unwrap();
        s.reuse_factor = reuse;
        s
    }

    /// The top of the cube held at `-d sin(pi x / l) sin(pi y / l)`.
    fn press_rows(mesh: &TetMesh, l: f64, d: f64) -> Vec<Prescribed> {
        nodes_where(mesh, |p| (p.z - l).abs() < 1e-12)
            .into_iter()
            .map(|node| {
                let p = mesh.nodes[node as usize];
                let s =
                    (std::f64::consts::PI * p.x / l).sin() * (std::f64::consts::PI * p.y / l).sin();
                Prescribed {
                    node,
                    displacement: Vector3::new(0.0, 0.0, -d * s),
                }
            })
            .collect()
    }

    /// Newton steps by conjugate gradients on an earlier factor solve the
    /// same linear systems to `1e-6` of their right-hand side, so the steps
    /// converge to the same
    /// equilibrium as the plain Newton method to the solver's tolerance
    /// (`1e-10` of the force): over a sequence of presses of up to 5 %
    /// strain (loading, further loading, unloading) the displacements
    /// agree to 1e-8 of the largest and the top's force to 1e-8 relative
    /// (the equilibria differ by the residual over the stiffness, about
    /// 1e-10 relative), while the reusing solve factors fewer times than
    /// it iterates.
    #[test]
    fn newton_on_an_earlier_factor_reaches_the_plain_newton_answer() {
        let l = 0.02;
        let mesh = cube(l, 3);
        let mut plain = press_strategy(&mesh, l, false);
        let mut reusing = press_strategy(&mesh, l, true);
        let mut iterations = 0;
        for d in [2e-4, 5e-4, 1e-3, 6e-4] {
            let rows = press_rows(&mesh, l, d);
            let a = plain.step(&rows).unwrap().clone();
            let b = reusing.step(&rows).unwrap().clone();
            iterations += u64::from(b.iterations);
            let scale = a.displacements.iter().fold(0.0f64, |m, u| m.max(u.norm()));
            let du = a
                .displacements
                .iter()
                .zip(&b.displacements)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).norm()));
            let (fa, fb): (f64, f64) = (
                a.reactions.iter().map(|r| r.z).sum(),
                b.reactions.iter().map(|r| r.z).sum(),
            );
            eprintln!(
                "d {d:e}: displacement {:.1e}, force {:.1e} relative; iterations {} / {}",
                du / scale,
                (fa - fb).abs() / fa.abs(),
                a.iterations,
                b.iterations
            );
            assert!(du <= 1e-8 * scale, "d {d:e}: {du:e} of {scale:e}");
            assert!((fa - fb).abs() <= 1e-8 * fa.abs(), "d {d:e}: {fa} vs {fb}");
        }
        assert!(
            reusing.factorizations < iterations,
            "{} factorizations in {iterations} iterations",
            reusing.factorizations
        );
        assert!(plain.factorizations > reusing.factorizations);
    }

    /// The tangent patch's factor is a function of the state: a step that
    /// ends where the last one did keeps it (no factorization, the same
    /// patch to the bit), one that moves makes a new one.
    #[test]
    fn the_tangent_patch_is_kept_while_the_state_stays() {
        let l = 0.02;
        let mesh = cube(l, 3);
        let mut s = press_strategy(&mesh, l, true);
        let rows = press_rows(&mesh, l, 4e-4);
        let nodes = nodes_where(&mesh, |p| (p.z - l / 3.0).abs() < 1e-12);
        let mut first = CompliancePatch::default();
        s.step(&rows).unwrap();
        assert!(s.tangent_patch(&nodes, &mut first));
        assert!(!first.nodes.is_empty());
        s.step(&rows).unwrap();
        assert!(s.tangent.is_fresh(), "the same state keeps the factor");
        let mut again = CompliancePatch::default();
        assert!(s.tangent_patch(&nodes, &mut again));
        assert_eq!(first, again);
        s.step(&press_rows(&mesh, l, 5e-4)).unwrap();
        assert!(!s.tangent.is_fresh(), "a new state makes a new factor");
    }

    /// Near incompressibility linear tetrahedra lock (one volumetric
    /// constraint per element, five to six per node) and the nodal-pressure
    /// element does not (one per node). On a 4 x 4 x 4 cube at a smooth
    /// 1 % press, `F(0.4999) / F(0.45)` of neo-Hookean with the
    /// nodal-pressure element stays within 3 % of the linear element's
    /// (at 1 % strain the two differ by O(strain); the ratio itself is
    /// near 1.1), while neo-Hookean tet4's exceeds three.
    #[test]
    fn neo_hookean_nodal_pressure_does_not_lock() {
        let l = 0.02;
        let mesh = cube(l, 4);
        let d = 2e-5;
        let ratio = |strategy, element| {
            let (_, f1) = smooth_press(&mesh, l, d, 0.45, strategy, element, None);
            let (_, f2) = smooth_press(&mesh, l, d, 0.4999, strategy, element, None);
            f2 / f1
        };
        let np = Element::Tet4NodalPressure;
        let linear = ratio(Strategy::Compliance, np);
        let nonlinear = ratio(Strategy::NeoHookean, np);
        let tet4 = ratio(Strategy::NeoHookean, Element::Tet4);
        eprintln!("F(0.4999) / F(0.45): {nonlinear} (linear {linear}), tet4 {tet4}");
        assert!(
            (nonlinear - linear).abs() < 0.03 * linear,
            "nodal pressure: neo-Hookean {nonlinear} vs linear {linear}"
        );
        assert!(linear < 1.5, "{linear}");
        assert!(tet4 > 3.0, "tet4 locks: {tet4}");
    }
}
