//! Strategy `corotational`: large rotation, small strain.
//!
//! Each element's rotation `R_e` is the polar factor of its deformation
//! gradient `F = Ds Dm^-1`; its internal force is
//! `f_e = R_e K_e (R_e^T x_e - X_e)` (rest positions `X`, current `x = X + u`).
//! A step solves `sum_e f_e = G^T lambda`, `G u = g` by Newton-like outer
//! iterations (rotations frozen within one: tangent `K_R = sum R K_e R^T`),
//! each solved by projected conjugate gradients preconditioned with the
//! constrained rest-state inverse (the `compliance` machinery: the supported
//! factor plus the compliance block of the step's rows).
//!
//! An elastic foundation ([`super::foundation::FoundationSprings`], springs
//! of fixed rest normals, not rotated with the elements) adds `K_f u` to the
//! internal force and `K_f` to the tangent `K_R`; the rest-state inverse
//! holds it already (`kel` does), so the preconditioner stays the inverse of
//! the tangent at rest. The tie springs ([`TieSprings`]) enter the same way.
//!
//! Warm start: the last good state plus the linear response to the change
//! of the enforced values (which meets them), so a small-rotation step
//! converges in one or two outer iterations; and, when the step has the
//! same constraint rows as the previous one (a spatula pushing on), plus the
//! previous step's nonlinear correction (its converged state minus its own
//! start), scaled by the projection of this step's change of the enforced
//! values on the previous one's, clamped to `[0, 1]` (the correction is
//! free: it vanishes on the constrained DOFs). On the 48k phantom, pushing
//! on, this cuts the first residual 3-4 times and saves an outer iteration
//! in most steps. A start that inverts an element falls back to the plain
//! one.
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
//! Cost per outer iteration: one pass over the elements for the rotations
//! and the internal force (in parallel under the caller's [`Par`]), then
//! per CG iteration one product with the rotated stiffness, applied element
//! by element from the rest shape-function gradients and the rotations
//! (`q_a = R sigma(R^T grad p) V g_a`: nothing is re-assembled or
//! re-factored, and the 12 x 12 element matrices are not read), and one
//! application of the rest-state constrained inverse (two sparse triangular
//! solves and the condensation of the contact rows, whose columns of
//! `K0^-1` are cached across steps). The triangular solves of the
//! preconditioner use a single-precision copy of the factor (half the
//! memory traffic; [`Compliance::keep_single`]); the CG uses the flexible
//! (Polak-Ribiere) `beta`, which tolerates the preconditioner's
//! single-precision asymmetry, and the convergence test is in double
//! precision, so the answer's accuracy does not depend on it. Element
//! results are summed per node through a node-to-element map, so the
//! answer does not depend on the number of threads.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::assembly::node_vec;
use super::compliance::{Compliance, Recover};
use super::constraint::Constraint;
use super::element::polar_rotation_fast;
use super::model::Model;
use super::par::{NodeGather, Par, for_each_chunk, try_for_each_chunk_pair};
use super::tangent::TangentPatch;
use super::ties::TieSprings;
use super::{CompliancePatch, Solution, SolveError};
use nalgebra::{Matrix3, Vector3};

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
/// out of the collision stage when a vertex already lies on a spatula face,
/// and zero ones when it touches without pushing) both `|r|` and `|f|`
/// sink to the rounding of the force computation, where their ratio is
/// noise of order 1: a purely relative test can never pass there, which is
/// how steps "did not converge (residual 0.998)" (forces formed from
/// absolute positions made that noise 1e-14 N even at zero displacement;
/// the strategies now form them from displacement differences, exactly
/// zero at rest, but a return to zero from a loaded state still ends in
/// rounding). The
/// floor is where the imbalance stops meaning anything: `1e-12 x E L^2`
/// (1.9e-10 N for the brain phantom: E = 3 kPa, L = 0.25 m) is the force
/// of a strain of 1e-12 over the model, while the rounding of `|r|` (about
/// `eps x E h^2 sqrt(DOFs)`, 2e-15 N on the 48k phantom, `h` = 4 mm the
/// element size) stays five orders below it. A genuinely diverging or
/// stalled solve still fails: the floor is absolute, four orders and more
/// below any load a spatula applies (about 1e-5 N at a 1 um push, tested
/// in `server/tests/engine/fem_convergence.rs`), and `max_outer` bounds the
/// iterations.
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
    /// paper-48k phantom this takes 2 to 3 outer iterations of
    /// `corotational` per step; the displacement then differs from a
    /// 1e-10 solve by about the same relative amount (1e-4 of the largest
    /// displacement, measured in `server/tests/engine/fem_solvers.rs`, well
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
    start: Vec<f64>,
    corr: Vec<f64>,
    corr_valid: bool,
    prev_rows: Vec<(u32, Vector3<f64>)>,
    prev_dg: Vec<f64>,
    dg: Vec<f64>,
    solution: Solution,
    support_reactions: Vec<Vector3<f64>>,
    /// Absolute floor of the convergence test, N.
    floor: f64,
    /// Total inner (CG) iterations of the last step.
    pub last_inner_iterations: u32,
    /// The tangent compliance of the last step, for the force loop.
    tangent: TangentPatch,
    /// The intact ties, as springs of the energy.
    springs: TieSprings,
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
        if model.pressure.is_some() {
            return Err(SolveError::InvalidModel(
                "the nodal-pressure element has no corotational form: strategy corotational \
                 takes tet4"
                    .into(),
            ));
        }
        let n = model.pattern.n_dofs;
        let ne = model.tets.len();
        let nn = model.n_nodes();
        let gather_map = NodeGather::new(nn, &model.tets);
        let par = super::par::default_par();
        let floor = model.force_floor(opts.floor_strain);
        let tangent = TangentPatch::new(&model)?;
        let mut lin = Compliance::new(model, Recover::All)?;
        lin.set_parallelism(par);
        lin.keep_single();
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
            start: vec![0.0; n],
            corr: vec![0.0; n],
            corr_valid: false,
            prev_rows: Vec::new(),
            prev_dg: Vec::new(),
            dg: Vec::new(),
            solution: Solution {
                displacements: vec![Vector3::zeros(); nn],
                ..Default::default()
            },
            support_reactions: Vec::new(),
            floor,
            last_inner_iterations: 0,
            tangent,
            springs: TieSprings::default(),
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

    /// Rotations and internal force at the current `u`, in one element
    /// pass: per element `H` ([`super::element::TetGeometry::displacement_gradient`]),
    /// `R = polar(I + H)`, the corotated strain `E = sym(R^T F) - I`
    /// evaluated as `sym((R^T - I) + R^T H)` (no cancellation at light load,
    /// exactly zero at rest), and `f_a = R sigma(E) V g_a`, which is
    /// `R K_e (R^T x_e - X_e)` (module documentation). Fails on an inverted
    /// element (the one of smallest index, whatever the parallelism).
    fn rotations_and_force(&mut self) -> Result<(), SolveError> {
        let m = self.lin.model();
        let u = &self.u;
        let failed = try_for_each_chunk_pair(
            self.par,
            &mut self.rot,
            1,
            &mut self.elem,
            12,
            MIN_ELEMS,
            |e0, rots, out| {
                for (k, (rot, o)) in rots.iter_mut().zip(out.chunks_exact_mut(12)).enumerate() {
                    let e = e0 + k;
                    let g = &m.geoms[e];
                    let h = g.displacement_gradient(&m.tets[e].map(|n| node_vec(u, n as usize)));
                    let f = Matrix3::identity() + h;
                    let Some(r) = polar_rotation_fast(&f) else {
                        return Some((e, f.determinant()));
                    };
                    *rot = r;
                    let rt = r.transpose();
                    let strain = (rt - Matrix3::identity()) + rt * h;
                    let [lambda, mu] = m.lame_pa[e];
                    write_forces(g, &(r * stress(&strain, lambda, mu)), o);
                }
                None
            },
        );
        match failed {
            Some((element, jacobian)) => Err(SolveError::Inverted { element, jacobian }),
            None => {
                self.gather_map.gather(self.par, &self.elem, &mut self.f);
                m.foundation.add_product(&m.tets, u, &mut self.f);
                self.springs.add_forces(&m.rest, u, &mut self.f);
                Ok(())
            }
        }
    }

    /// `q = K_R p`, `K_R = sum_e R_e K_e R_e^T`, never assembled: per
    /// element `q_a = R sigma(R^T grad p) V g_a` (the rest geometry and the
    /// rotations are all it needs; `K_e` itself, 1.2 kB an element, is not
    /// read).
    fn tangent_matvec(&mut self) {
        let m = self.lin.model();
        let (rot, x) = (&self.rot, &self.p);
        for_each_chunk(self.par, &mut self.elem, 12, MIN_ELEMS, |first, out| {
            let e0 = first / 12;
            for (k, o) in out.chunks_exact_mut(12).enumerate() {
                let e = e0 + k;
                let (g, r) = (&m.geoms[e], &rot[e]);
                let grad = g.displacement_gradient(&m.tets[e].map(|n| node_vec(x, n as usize)));
                let [lambda, mu] = m.lame_pa[e];
                write_forces(g, &(r * stress(&(r.transpose() * grad), lambda, mu)), o);
            }
        });
        self.gather_map.gather(self.par, &self.elem, &mut self.q);
        m.foundation.add_product(&m.tets, &self.p, &mut self.q);
        self.springs
            .add_product(&m.rest, &self.u, &self.p, &mut self.q);
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

    /// The start of a step (module documentation, "Warm start"): the last
    /// good state plus the linear response to the change `dg` of the
    /// enforced values (kept in `self.start`), plus the previous step's
    /// nonlinear correction scaled by `s = clamp(dg . dg_prev / |dg_prev|^2,
    /// 0, 1)` when the step has the same constraint rows as the previous
    /// one. Returns whether the correction was added.
    fn warm_start(&mut self) -> bool {
        self.u.copy_from_slice(&self.good);
        let rows = &self.lin.step_rows().rows;
        self.dg.clear();
        self.dg.extend(
            rows.iter()
                .map(|r| r.value - r.dir.dot(&node_vec(&self.u, r.node as usize))),
        );
        let same_rows = self.corr_valid
            && self.prev_rows.len() == rows.len()
            && self
                .prev_rows
                .iter()
                .zip(rows)
                .all(|(a, b)| a.0 == b.node && a.1 == b.dir);
        self.lin.lift(&mut self.u);
        self.start.copy_from_slice(&self.u);
        if !same_rows {
            return false;
        }
        let num: f64 = self.dg.iter().zip(&self.prev_dg).map(|(a, b)| a * b).sum();
        let den: f64 = self.prev_dg.iter().map(|b| b * b).sum();
        let s = if den > 0.0 {
            (num / den).clamp(0.0, 1.0)
        } else {
            0.0
        };
        if !(s > 0.0) {
            return false;
        }
        for (u, c) in self.u.iter_mut().zip(&self.corr) {
            *u += s * c;
        }
        true
    }

    /// Remembers the converged step's nonlinear correction (`u - start`),
    /// its rows and its change of the enforced values for the next start.
    fn remember_correction(&mut self) {
        for ((c, u), s0) in self.corr.iter_mut().zip(&self.u).zip(&self.start) {
            *c = u - s0;
        }
        self.corr_valid = true;
        self.prev_rows.clear();
        self.prev_rows
            .extend(self.lin.step_rows().rows.iter().map(|r| (r.node, r.dir)));
        std::mem::swap(&mut self.prev_dg, &mut self.dg);
    }

    /// Outer iterations: rotations and internal force at `u`, then an
    /// inexact Newton step by PCG on `K_R du = -P f` (forcing term 0.1:
    /// with the rest-state inverse as preconditioner one or two CG
    /// iterations usually reach it).
    fn iterate(&mut self) -> Result<u32, SolveError> {
        let extrapolated = self.warm_start();
        self.last_inner_iterations = 0;
        for outer in 1..=self.opts.max_outer {
            if let Err(e) = self.rotations_and_force() {
                if !(extrapolated && outer == 1) {
                    return Err(e);
                }
                // The extrapolated start inverts an element: start without.
                self.u.copy_from_slice(&self.start);
                self.rotations_and_force()?;
            }
            self.r.copy_from_slice(&self.f);
            Self::project(&self.lin, &mut self.r);
            let res = Self::dot(&self.r, &self.r).sqrt();
            let total = Self::dot(&self.f, &self.f).sqrt();
            if !(res.is_finite() && total.is_finite()) {
                return Err(SolveError::NonFinite("corotational residual".into()));
            }
            let threshold = self.opts.threshold(total, self.floor);
            if res <= threshold {
                self.remember_correction();
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
                // Flexible (Polak-Ribiere) beta: r_new . (z_new - z_old),
                // robust to a preconditioner that is not exactly symmetric.
                let rz_old_new = Self::dot(&self.r, &self.z);
                self.z.copy_from_slice(&self.r);
                self.lin.constrained_solve(&mut self.z);
                Self::project(&self.lin, &mut self.z);
                let rz_new = Self::dot(&self.r, &self.z);
                let beta = (rz_new - rz_old_new) / rz;
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
        self.corr_valid = false;
        self.good.fill(0.0);
        self.u.fill(0.0);
        self.f.fill(0.0);
        self.rot.fill(Matrix3::identity());
    }

    fn step<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<&Solution, SolveError> {
        self.tangent.invalidate();
        self.lin.prepare_constraints(cons)?;
        let iterations = if self.lin.step_rows().rows.is_empty() && self.springs.pairs.is_empty() {
            // Nothing enforced: the rest state is the equilibrium (ties
            // are seeded at their rest length, but the springs are solved
            // for all the same).
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
                    self.corr_valid = false;
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

/// Linear-elastic stress `sigma(sym(a))` (Pa) for a
/// displacement-gradient-like `a`: `2 mu eps + lambda tr(eps) I`,
/// `eps = (a + a^T) / 2`.
#[inline]
fn stress(a: &Matrix3<f64>, lambda: f64, mu: f64) -> Matrix3<f64> {
    let eps = a + a.transpose();
    let mut s = mu * eps;
    let t = 0.5 * lambda * eps.trace();
    for i in 0..3 {
        s[(i, i)] += t;
    }
    s
}

/// Element nodal forces `f_a = V P g_a` (N) for a stress-like `P` into `o`
/// (12 values): the product `K_e v` of the linear element stiffness when
/// `P = sigma(grad v)` ([`super::element::TetGeometry::stiffness`]).
#[inline]
fn write_forces(g: &super::element::TetGeometry, p: &Matrix3<f64>, o: &mut [f64]) {
    let pv = g.volume * p;
    for a in 0..4 {
        let v = pv * g.grads[a];
        o[3 * a..3 * a + 3].copy_from_slice(v.as_slice());
    }
}

impl Corotational {
    /// The force loop's patch: the compliance of the frozen-rotation
    /// tangent `K_R = sum_e R_e K_e R_e^T` at the last good state (the
    /// tangent the outer iterations solve with; [`super::tangent`]).
    /// `false` when the state cannot be evaluated or factored.
    fn tangent_patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) -> bool {
        if !self.tangent.is_fresh() {
            // Rotations and internal force of the last good state (after a
            // failed step they are of a trial).
            self.u.copy_from_slice(&self.good);
            if self.rotations_and_force().is_err() {
                return false;
            }
        }
        let m = self.lin.model();
        let rot = &self.rot;
        let refactored = self.tangent.refactor(
            m,
            |e| {
                let r = rot[e];
                // The element's own stiffness: the foundation's springs
                // (in `kel` too) hold fixed normals and do not rotate; the
                // refactor adds them unrotated.
                let mut k = m.kel[e];
                if let Some(kf) = m.foundation.matrix_of(e) {
                    k -= kf;
                }
                for a in 0..4 {
                    for b in 0..4 {
                        let kab: Matrix3<f64> = k.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                        k.fixed_view_mut::<3, 3>(3 * a, 3 * b)
                            .copy_from(&(r * kab * r.transpose()));
                    }
                }
                Some(k)
            },
            &self.springs,
            None,
            &self.u,
        );
        if refactored.is_err() {
            return false;
        }
        self.tangent.fill(
            self.lin.model(),
            nodes,
            &self.solution.displacements,
            &self.f,
            patch,
        );
        true
    }
}

/// The `corotational` strategy ([`super::StrategyKind`]).
pub const KIND: super::StrategyKind = super::StrategyKind {
    name: "corotational",
    label: "corot",
    linear: false,
    material_model: "corotational",
    build: |model, options| {
        let mut c = Corotational::new(model, options.iterative)?;
        c.set_parallelism(options.parallelism);
        if let Some(n) = options.cache_nodes {
            c.set_cache_limit(n);
        }
        Ok(Box::new(c))
    },
};

stepping_solver!(
    Corotational,
    KIND.name,
    [lin.model()]
    fn compliance_patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) -> bool {
        self.tangent_patch(nodes, patch)
    }

    fn set_tie_springs(&mut self, springs: &TieSprings) -> bool {
        if self.springs != *springs {
            self.springs.clone_from(springs);
            self.tangent.invalidate();
            // The last correction was of other springs.
            self.corr_valid = false;
        }
        true
    }
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::element::{TetGeometry, polar_rotation};
    use nalgebra::{Point3, SVector};

    fn tet() -> TetGeometry {
        TetGeometry::new([
            Point3::new(-0.051, 0.012, 0.003),
            Point3::new(-0.047, 0.0125, 0.0028),
            Point3::new(-0.0505, 0.0158, 0.0035),
            Point3::new(-0.0498, 0.0127, 0.0069),
        ])
        .unwrap()
    }

    #[test]
    fn element_kernels_equal_the_element_stiffness() {
        let g = tet();
        let rest = [
            Vector3::new(-0.051, 0.012, 0.003),
            Vector3::new(-0.047, 0.0125, 0.0028),
            Vector3::new(-0.0505, 0.0158, 0.0035),
            Vector3::new(-0.0498, 0.0127, 0.0069),
        ];
        let (lambda, mu) = (9.3e3, 1.03e3);
        let k = g.stiffness(lambda, mu);
        let v = [
            Vector3::new(1e-4, -2e-4, 3e-5),
            Vector3::new(-4e-5, 1e-4, 2e-4),
            Vector3::new(3e-4, 5e-5, -1e-4),
            Vector3::new(-2e-4, -1e-4, 1e-4),
        ];
        let flat = |v: &[Vector3<f64>; 4]| {
            SVector::<f64, 12>::from_iterator(v.iter().flat_map(|x| x.iter().copied()))
        };
        // Linear: K_e v.
        let mut o = [0.0; 12];
        write_forces(
            &g,
            &stress(&g.displacement_gradient(&v), lambda, mu),
            &mut o,
        );
        let want = k * flat(&v);
        for i in 0..12 {
            assert!((o[i] - want[i]).abs() < 1e-12 * want.norm(), "{i}");
        }
        // Corotational: R K_e (R^T x - X) at a large rotation and a strain.
        let rot = nalgebra::Rotation3::from_euler_angles(0.7, -0.3, 1.2).into_inner();
        let c = rest[0];
        let u = rest.map(|x| rot * (x - c + 0.5 * v[0].component_mul(&(x - c)) * 1e3) + c - x);
        let h = g.displacement_gradient(&u);
        let r = polar_rotation(&(Matrix3::identity() + h));
        let rt = r.transpose();
        write_forces(
            &g,
            &(r * stress(&((rt - Matrix3::identity()) + rt * h), lambda, mu)),
            &mut o,
        );
        let loc: [Vector3<f64>; 4] = std::array::from_fn(|a| rt * (rest[a] + u[a]) - rest[a]);
        let kx = k * flat(&loc);
        for a in 0..4 {
            let want = r * kx.fixed_rows::<3>(3 * a);
            for i in 0..3 {
                assert!((o[3 * a + i] - want[i]).abs() < 1e-9 * kx.norm(), "{a} {i}");
            }
        }
    }
}
