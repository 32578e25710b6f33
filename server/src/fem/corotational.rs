//! Strategy `corotational`: large rotation, small strain.
//!
//! Each element's rotation `R_e` is the polar factor of its deformation
//! gradient `F = Ds Dm^-1`; its internal force is
//! `f_e = R_e K_e (R_e^T x_e - X_e)` (rest positions `X`, current `x = X + u`).
//! A step solves `sum_e f_e = G^T lambda`, `G u = g` by Newton-like outer
//! iterations (rotations frozen within one: tangent `K_R = sum R K_e R^T`),
//! each solved by projected conjugate gradients preconditioned with the exact
//! constrained rest-state inverse (the `compliance` machinery: the supported
//! factor plus the compliance block of the step's rows). The start is the
//! last good state plus the linear response to the change of the enforced
//! values, so a small-rotation step converges in one or two outer iterations.
//!
//! Convergence: `|P f| <= tol (|f_c| + tiny)`, with `P` the projection off the
//! constrained and supported DOFs and `f_c` the internal force at them.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::assembly::{gather, node_vec, scatter_add};
use super::compliance::{Compliance, Recover};
use super::constraint::Constraint;
use super::element::polar_rotation_fast;
use super::model::Model;
use super::{DeformationSolver, LocalModel, Prescribed, Solution, SolveError};
use nalgebra::{Matrix3, SVector, Vector3};

/// Tolerances of the iterative strategies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IterativeOptions {
    /// Relative residual at convergence.
    pub tolerance: f64,
    /// Most outer (Newton) iterations per step.
    pub max_outer: u32,
    /// Most inner (CG) iterations per outer iteration (corotational).
    pub max_inner: u32,
}

impl Default for IterativeOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-6,
            max_outer: 30,
            max_inner: 100,
        }
    }
}

/// The `corotational` strategy.
pub struct Corotational {
    lin: Compliance,
    opts: IterativeOptions,
    rot: Vec<Matrix3<f64>>,
    u: Vec<f64>,
    f: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    du: Vec<f64>,
    good: Vec<f64>,
    solution: Solution,
    support_reactions: Vec<Vector3<f64>>,
    /// Total inner (CG) iterations of the last step.
    pub last_inner_iterations: u32,
}

impl std::fmt::Debug for Corotational {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Corotational")
            .field("opts", &self.opts)
            .finish()
    }
}

impl Corotational {
    /// Factors the rest-state supported stiffness.
    pub fn new(model: Model, opts: IterativeOptions) -> Result<Self, SolveError> {
        let n = model.pattern.n_dofs;
        let ne = model.tets.len();
        let nn = model.n_nodes();
        Ok(Self {
            lin: Compliance::new(model, Recover::All)?,
            opts,
            rot: vec![Matrix3::identity(); ne],
            u: vec![0.0; n],
            f: vec![0.0; n],
            r: vec![0.0; n],
            z: vec![0.0; n],
            p: vec![0.0; n],
            q: vec![0.0; n],
            du: vec![0.0; n],
            good: vec![0.0; n],
            solution: Solution {
                displacements: vec![Vector3::zeros(); nn],
                ..Default::default()
            },
            support_reactions: Vec::new(),
            last_inner_iterations: 0,
        })
    }

    /// Rotations from the current `u`; fails on an inverted element.
    fn update_rotations(&mut self) -> Result<(), SolveError> {
        let m = self.lin.model();
        for (e, t) in m.tets.iter().enumerate() {
            let x = t.map(|n| m.rest[n as usize].coords + node_vec(&self.u, n as usize));
            let f = m.geoms[e].deformation_gradient(&x);
            let j = f.determinant();
            match polar_rotation_fast(&f) {
                Some(r) => self.rot[e] = r,
                None => {
                    return Err(SolveError::Inverted {
                        element: e,
                        jacobian: j,
                    });
                }
            }
        }
        Ok(())
    }

    /// Internal force `f = sum_e R K_e (R^T x_e - X_e)` into `self.f`.
    fn internal_force(&mut self) {
        let m = self.lin.model();
        self.f.fill(0.0);
        for (e, t) in m.tets.iter().enumerate() {
            let r = &self.rot[e];
            let mut loc = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                let n = t[a] as usize;
                let x = m.rest[n].coords + node_vec(&self.u, n);
                let v = r.transpose() * x - m.rest[n].coords;
                loc.fixed_rows_mut::<3>(3 * a).copy_from(&v);
            }
            let k = m.kel[e] * loc;
            let mut out = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                out.fixed_rows_mut::<3>(3 * a)
                    .copy_from(&(r * k.fixed_rows::<3>(3 * a)));
            }
            scatter_add(t, &out, &mut self.f);
        }
    }

    /// `y = K_R x`.
    fn tangent_matvec(lin: &Compliance, rot: &[Matrix3<f64>], x: &[f64], y: &mut [f64]) {
        let m = lin.model();
        y.fill(0.0);
        for (e, t) in m.tets.iter().enumerate() {
            let r = &rot[e];
            let xe = gather(t, x);
            let mut loc = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                loc.fixed_rows_mut::<3>(3 * a)
                    .copy_from(&(r.transpose() * xe.fixed_rows::<3>(3 * a)));
            }
            let k = m.kel[e] * loc;
            let mut out = SVector::<f64, 12>::zeros();
            for a in 0..4 {
                out.fixed_rows_mut::<3>(3 * a)
                    .copy_from(&(r * k.fixed_rows::<3>(3 * a)));
            }
            scatter_add(t, &out, y);
        }
    }

    /// Projection off the supports and the step's constraint rows.
    fn project(lin: &Compliance, v: &mut [f64]) {
        let m = lin.model();
        for (x, &s) in v.iter_mut().zip(&m.support) {
            if s {
                *x = 0.0;
            }
        }
        for row in &lin.step_rows().rows {
            let n = row.node as usize;
            let c = row.dir.dot(&node_vec(v, n));
            for a in 0..3 {
                v[3 * n + a] -= c * row.dir[a];
            }
        }
    }

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    fn iterate(&mut self) -> Result<u32, SolveError> {
        // Start: last good state plus the linear response to the new values.
        self.u.copy_from_slice(&self.good);
        self.lin.lift(&mut self.u);
        self.last_inner_iterations = 0;
        for outer in 1..=self.opts.max_outer {
            self.update_rotations()?;
            self.internal_force();
            self.r.copy_from_slice(&self.f);
            Self::project(&self.lin, &mut self.r);
            let res = Self::dot(&self.r, &self.r).sqrt();
            let total = Self::dot(&self.f, &self.f).sqrt();
            if !res.is_finite() {
                return Err(SolveError::NonFinite("corotational residual".into()));
            }
            if res <= self.opts.tolerance * total || res == 0.0 {
                return Ok(outer);
            }
            if outer == self.opts.max_outer {
                return Err(SolveError::NotConverged {
                    iterations: outer,
                    residual: res / total.max(f64::MIN_POSITIVE),
                });
            }
            // PCG on K_R du = -P f in the constrained subspace.
            for v in self.r.iter_mut() {
                *v = -*v;
            }
            self.du.fill(0.0);
            self.z.copy_from_slice(&self.r);
            self.lin.constrained_solve(&mut self.z);
            Self::project(&self.lin, &mut self.z);
            self.p.copy_from_slice(&self.z);
            let mut rz = Self::dot(&self.r, &self.z);
            let r0 = res;
            for _ in 0..self.opts.max_inner {
                self.last_inner_iterations += 1;
                Self::tangent_matvec(&self.lin, &self.rot, &self.p, &mut self.q);
                Self::project(&self.lin, &mut self.q);
                let pq = Self::dot(&self.p, &self.q);
                if !(pq > 0.0) {
                    break;
                }
                let alpha = rz / pq;
                for i in 0..self.du.len() {
                    self.du[i] += alpha * self.p[i];
                    self.r[i] -= alpha * self.q[i];
                }
                let rn = Self::dot(&self.r, &self.r).sqrt();
                // Inexact Newton: a modest relative reduction per outer step,
                // tighter than the outer tolerance near convergence.
                if rn <= (1e-3 * r0).max(0.1 * self.opts.tolerance * total) {
                    break;
                }
                self.z.copy_from_slice(&self.r);
                self.lin.constrained_solve(&mut self.z);
                Self::project(&self.lin, &mut self.z);
                let rz_new = Self::dot(&self.r, &self.z);
                let beta = rz_new / rz;
                rz = rz_new;
                for i in 0..self.p.len() {
                    self.p[i] = self.z[i] + beta * self.p[i];
                }
            }
            for (u, d) in self.u.iter_mut().zip(&self.du) {
                *u += d;
            }
        }
        unreachable!("the loop returns at max_outer")
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.lin.prepare_constraints(cons)?;
        let iterations = match self.iterate() {
            Ok(i) => i,
            Err(e) => {
                // Keep the last good state (rotations follow it lazily).
                self.u.copy_from_slice(&self.good);
                return Err(e);
            }
        };
        self.good.copy_from_slice(&self.u);
        for (i, d) in self.solution.displacements.iter_mut().enumerate() {
            *d = node_vec(&self.u, i);
        }
        self.lin
            .step_rows()
            .reactions_from_forces(&self.f, &mut self.solution.reactions);
        self.support_reactions.clear();
        let m = self.lin.model();
        self.support_reactions
            .extend(m.fixed.iter().map(|&n| node_vec(&self.f, n as usize)));
        self.solution.iterations = iterations;
        Ok(&self.solution)
    }
}

impl DeformationSolver for Corotational {
    fn name(&self) -> &'static str {
        "corotational"
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
