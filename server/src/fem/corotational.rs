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
//! Convergence (see [`IterativeOptions`]): `|P f| <= max(tol |f|, F_floor)`,
//! with `P` the projection off the constrained and supported DOFs, `f` the
//! internal force (the reactions at the constrained and supported DOFs
//! plus the free imbalance) and `F_floor` an absolute floor in newtons. The
//! default `tol` is [`IterativeOptions::INTERACTIVE_TOLERANCE`] (1e-4),
//! meant for interactive rates; use [`IterativeOptions::reference`] for
//! reference solutions.
//!
//! Kinematics in displacement differences: the rotation is the polar factor
//! of `F = I + H`, `H` from [`super::element::TetGeometry::displacement_gradient`],
//! and the element force is evaluated relative to the element's first
//! corner, `v_a = R^T u_a + (R^T - I) (X_a - X_0)`, which differs from
//! `R^T x_a - X_a` by a translation common to the four corners (`K_e`
//! annihilates it). No absolute position enters, so the force keeps full
//! relative precision at light load and is exactly zero at rest.
//!
//! Cost per outer iteration: one rotation extraction and one internal force
//! (per element, in parallel under the caller's [`Par`]), then per CG
//! iteration one product with the rotated stiffness, applied element by
//! element from the rest element matrices and the rotations (nothing is
//! re-assembled or re-factored), and one application of the rest-state
//! constrained inverse (two sparse triangular solves and the condensation
//! of the contact rows, whose columns of `K0^-1` are cached across steps).
//! Element results are summed per node through a node-to-element map, so
//! the answer does not depend on the number of threads.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::assembly::{gather, node_vec};
use super::compliance::{Compliance, Recover};
use super::constraint::Constraint;
use super::element::polar_rotation_fast;
use super::model::Model;
use super::par::{NodeGather, Par, for_each_chunk, try_for_each_chunk};
use super::{DeformationSolver, LocalModel, Prescribed, Solution, SolveError};
use nalgebra::{Matrix3, SVector, Vector3};

/// Tolerances of the iterative strategies (`corotational`, `neo-hookean`).
///
/// **Convergence test.** With `r` the force imbalance at the free DOFs (N;
/// the internal force projected off the constrained and supported DOFs)
/// and `f` the internal force at every DOF (N), an iterate is converged when
///
/// `|r| <= max(tolerance x |f|, F_floor)`,  `F_floor = floor_strain x E x L^2`
///
/// (`E` Young's modulus in Pa, `L` the diagonal of the rest bounding box in
/// m, [`super::model::Model::force_floor`]). `|f|` is the load scale: at
/// equilibrium it is the norm of the reactions (constraints and supports),
/// which the enforced displacements imply, so the relative part is
/// independent of the units and of the size of the load. It vanishes with
/// the load, and at light contact (enforced displacements of 1e-18 m come
/// out of the collision stage when a vertex already lies on a spatula face)
/// both `|r|` and `|f|` sink to the rounding of the force computation,
/// where their ratio is noise of order 1: a purely relative test can never
/// pass there, which is how steps "did not converge (residual 0.998)". The
/// floor is where the imbalance stops meaning anything: `1e-12 x E L^2`
/// (7e-11 N for the 48k phantom: E = 3 kPa, L = 0.15 m) moves a node by
/// about `1e-12 L`, while the rounding of `|r|` (about
/// `eps x E h^2 sqrt(DOFs)`, 1e-14 N there, `h` the element size) stays
/// three orders below it. A genuinely diverging or stalled solve still
/// fails: the floor is absolute, far below any load a spatula applies
/// (1e-5 N at a 1 um push), and `max_outer` bounds the iterations.
/// `NotConverged` reports `|r| / max(|f|, F_floor / tolerance)`, which is
/// `<= tolerance` exactly when the test passes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IterativeOptions {
    /// Relative residual at convergence (the `tolerance` of the test
    /// above). Default [`IterativeOptions::INTERACTIVE_TOLERANCE`].
    pub tolerance: f64,
    /// Most outer (Newton) iterations per step.
    pub max_outer: u32,
    /// Most inner (CG) iterations per outer iteration (corotational).
    pub max_inner: u32,
    /// The absolute floor of the test as a strain (dimensionless): the
    /// floor is `floor_strain x E x L^2` newtons. Default
    /// [`IterativeOptions::DEFAULT_FLOOR_STRAIN`]; 0 makes the test purely
    /// relative.
    pub floor_strain: f64,
}

impl IterativeOptions {
    /// The default relative residual, chosen for interactive rates: the
    /// free-DOF force imbalance is 1e-4 of the contact forces. On the
    /// paper-48k phantom this takes 1 to 3 outer iterations of
    /// `corotational` per step; the displacement then differs from a
    /// 1e-10 solve by about the same relative amount (1e-4 of the largest
    /// displacement, measured in `server/tests/fem_corotational.rs`, well
    /// below the P1 discretisation error). The accuracy reference
    /// (`neo-hookean` in the study) should use 1e-8 or below.
    pub const INTERACTIVE_TOLERANCE: f64 = 1e-4;

    /// The default floor strain, 1e-12 (see the type's documentation).
    pub const DEFAULT_FLOOR_STRAIN: f64 = 1e-12;

    /// The test's threshold on the free imbalance, N, for the internal
    /// force norm `total` (N) and the floor `floor` (N).
    pub fn threshold(&self, total: f64, floor: f64) -> f64 {
        (self.tolerance * total).max(floor)
    }

    /// The residual `NotConverged` reports: `res / max(total, floor /
    /// tolerance)` (<= `tolerance` exactly when the test passes).
    pub fn relative_residual(&self, res: f64, total: f64, floor: f64) -> f64 {
        let scale = if self.tolerance > 0.0 {
            total.max(floor / self.tolerance)
        } else {
            total
        };
        res / scale.max(f64::MIN_POSITIVE)
    }

    /// Tight options for reference solutions (relative residual 1e-10).
    pub fn reference() -> Self {
        Self {
            tolerance: 1e-10,
            ..Self::default()
        }
    }
}

impl Default for IterativeOptions {
    fn default() -> Self {
        Self {
            tolerance: Self::INTERACTIVE_TOLERANCE,
            max_outer: 30,
            max_inner: 100,
            floor_strain: Self::DEFAULT_FLOOR_STRAIN,
        }
    }
}

/// The `corotational` strategy.
pub struct Corotational {
    lin: Compliance,
    opts: IterativeOptions,
    par: Par,
    gather_map: NodeGather,
    rot: Vec<Matrix3<f64>>,
    elem: Vec<f64>,
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
    /// Absolute floor of the convergence test, N.
    floor: f64,
    /// Total inner (CG) iterations of the last step.
    pub last_inner_iterations: u32,
}

impl std::fmt::Debug for Corotational {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Corotational")
            .field("opts", &self.opts)
            .field("par", &self.par)
            .finish()
    }
}

/// Smallest per-task chunk of elements.
const MIN_ELEMS: usize = 512;

impl Corotational {
    /// Factors the rest-state supported stiffness; element loops run with
    /// every thread of the current rayon pool (see [`Self::set_parallelism`]).
    pub fn new(model: Model, opts: IterativeOptions) -> Result<Self, SolveError> {
        let n = model.pattern.n_dofs;
        let ne = model.tets.len();
        let nn = model.n_nodes();
        let gather_map = NodeGather::new(nn, &model.tets);
        let par = super::par::default_par();
        let floor = model.force_floor(opts.floor_strain);
        let mut lin = Compliance::new(model, Recover::All)?;
        lin.set_parallelism(par);
        Ok(Self {
            lin,
            opts,
            par,
            gather_map,
            rot: vec![Matrix3::identity(); ne],
            elem: vec![0.0; 12 * ne],
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
            floor,
            last_inner_iterations: 0,
        })
    }

    /// Parallelism of the element loops and of the linear algebra
    /// (the results do not depend on it).
    pub fn set_parallelism(&mut self, par: Par) {
        self.par = par;
        self.lin.set_parallelism(par);
    }

    /// Bound of the cache of `K0^-1` columns (see
    /// [`Compliance::set_cache_limit`]).
    pub fn set_cache_limit(&mut self, nodes: usize) {
        self.lin.set_cache_limit(nodes);
    }

    /// The rest-state condensation used as preconditioner.
    pub fn linear(&self) -> &Compliance {
        &self.lin
    }

    /// Rotations from the current `u`; fails on an inverted element (the
    /// one of smallest index).
    fn update_rotations(&mut self) -> Result<(), SolveError> {
        let m = self.lin.model();
        let u = &self.u;
        let failed = try_for_each_chunk(self.par, &mut self.rot, 1, MIN_ELEMS, |e0, rots| {
            for (k, rot) in rots.iter_mut().enumerate() {
                let e = e0 + k;
                let t = &m.tets[e];
                let ue = t.map(|n| node_vec(u, n as usize));
                let f = Matrix3::identity() + m.geoms[e].displacement_gradient(&ue);
                match polar_rotation_fast(&f) {
                    Some(r) => *rot = r,
                    None => return Some((e, f.determinant())),
                }
            }
            None
        });
        match failed {
            Some((element, jacobian)) => Err(SolveError::Inverted { element, jacobian }),
            None => Ok(()),
        }
    }

    /// Internal force `f = sum_e R K_e (R^T x_e - X_e)` into `self.f`,
    /// evaluated as `R K_e v` with `v_a = R^T u_a + (R^T - I)(X_a - X_0)`
    /// (the same up to a common translation, which `K_e` annihilates; no
    /// absolute position, see the module documentation).
    fn internal_force(&mut self) {
        let m = self.lin.model();
        let (u, rot) = (&self.u, &self.rot);
        for_each_chunk(self.par, &mut self.elem, 12, MIN_ELEMS, |first, out| {
            let e0 = first / 12;
            for (k, o) in out.chunks_exact_mut(12).enumerate() {
                let e = e0 + k;
                let (t, r) = (&m.tets[e], &rot[e]);
                let rt = r.transpose();
                let rt_minus_i = rt - Matrix3::identity();
                let x0 = m.rest[t[0] as usize].coords;
                let mut loc = SVector::<f64, 12>::zeros();
                for a in 0..4 {
                    let n = t[a] as usize;
                    let v = rt * node_vec(u, n) + rt_minus_i * (m.rest[n].coords - x0);
                    loc.fixed_rows_mut::<3>(3 * a).copy_from(&v);
                }
                let kx = m.kel[e] * loc;
                for a in 0..4 {
                    let v = r * kx.fixed_rows::<3>(3 * a);
                    o[3 * a..3 * a + 3].copy_from_slice(v.as_slice());
                }
            }
        });
        self.gather_map.gather(self.par, &self.elem, &mut self.f);
    }

    /// `q = K_R p`, `K_R = sum_e R_e K_e R_e^T` (never assembled: the rest
    /// element matrices and the rotations are all it needs).
    fn tangent_matvec(&mut self) {
        let m = self.lin.model();
        let (rot, x) = (&self.rot, &self.p);
        for_each_chunk(self.par, &mut self.elem, 12, MIN_ELEMS, |first, out| {
            let e0 = first / 12;
            for (k, o) in out.chunks_exact_mut(12).enumerate() {
                let e = e0 + k;
                let (t, r) = (&m.tets[e], &rot[e]);
                let xe = gather(t, x);
                let mut loc = SVector::<f64, 12>::zeros();
                for a in 0..4 {
                    loc.fixed_rows_mut::<3>(3 * a)
                        .copy_from(&(r.transpose() * xe.fixed_rows::<3>(3 * a)));
                }
                let kx = m.kel[e] * loc;
                for a in 0..4 {
                    let v = r * kx.fixed_rows::<3>(3 * a);
                    o[3 * a..3 * a + 3].copy_from_slice(v.as_slice());
                }
            }
        });
        self.gather_map.gather(self.par, &self.elem, &mut self.q);
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

    /// Outer iterations: rotations and internal force at `u`, then an
    /// inexact Newton step by PCG on `K_R du = -P f` (forcing term 0.1:
    /// with the rest-state inverse as preconditioner one or two CG
    /// iterations usually reach it).
    fn iterate(&mut self) -> Result<u32, SolveError> {
        // Warm start: last good state plus the linear response to the
        // change of the enforced values.
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
            if !(res.is_finite() && total.is_finite()) {
                return Err(SolveError::NonFinite("corotational residual".into()));
            }
            let threshold = self.opts.threshold(total, self.floor);
            if res <= threshold {
                return Ok(outer);
            }
            if outer == self.opts.max_outer {
                return Err(SolveError::NotConverged {
                    iterations: outer,
                    residual: self.opts.relative_residual(res, total, self.floor),
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
                self.tangent_matvec();
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
                // Inexact Newton: a relative reduction of 0.1 per outer
                // step, tighter than the outer tolerance near convergence.
                if rn <= (0.1 * r0).max(0.1 * threshold) {
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

    /// Back to rest: zero displacement, identity rotations, no warm start.
    fn reset(&mut self) {
        self.good.fill(0.0);
        self.u.fill(0.0);
        self.f.fill(0.0);
        self.rot.fill(Matrix3::identity());
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.lin.prepare_constraints(cons)?;
        let iterations = if self.lin.step_rows().rows.is_empty() {
            // Nothing enforced: the rest state is the equilibrium.
            self.reset();
            self.last_inner_iterations = 0;
            1
        } else {
            match self.iterate() {
                Ok(i) if self.u.iter().all(|v| v.is_finite()) => i,
                Ok(_) => {
                    self.u.copy_from_slice(&self.good);
                    return Err(SolveError::NonFinite("corotational displacement".into()));
                }
                Err(e) => {
                    // Keep the last good state (rotations follow it lazily).
                    self.u.copy_from_slice(&self.good);
                    return Err(e);
                }
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
