//! The skull as unilateral spherical constraints, solved by an active set
//! around any strategy: a *containing* sphere that nodes may not leave and an
//! *excluding* sphere that nodes may not enter.
//!
//! Each round solves with the step's constraints plus, for every active node,
//! a normal-only constraint putting it on the sphere along the radial
//! direction `n = (x - c) / |x - c|` (`n . u = R - n . (X - c)`, linearised
//! at the node's last position). A node becomes active when it violates the
//! sphere (by more than `1e-9 R`); it is released when its multiplier pulls
//! (for the containing sphere, the skull may only push inward: `r . n <= 0`;
//! for the excluding sphere `r . n >= 0`). Rounds stop when the set no longer
//! changes (at most `max_rounds`). Only the surface nodes are candidates.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{
    Constraint, ConstraintKind, DeformationSolver, LocalModel, Prescribed, Solution, SolveError,
};
use nalgebra::{Point3, Vector3};

/// A sphere, m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Centre, m.
    pub centre: Point3<f64>,
    /// Radius, m (> 0).
    pub radius: f64,
}

/// The skull spheres a scene asks for.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Skull {
    /// Nodes may not leave this sphere.
    pub containing: Option<Sphere>,
    /// Nodes may not enter this sphere.
    pub excluding: Option<Sphere>,
}

/// The skull as the brain's rest outer surface offset outward by the CSF
/// layer: each supported surface node `v` (rest position `X_v`, unit outward
/// area-weighted rest normal `n_v`) meets the skull at `X_v + g n_v`, and
/// the skull there is taken as the plane through that point normal to
/// `n_v` (the offset surface's tangent plane, exact for a flat patch and
/// first-order accurate in `g` times the surface's curvature). The node
/// may not cross it: `n_v . u_v <= g`, a unilateral contact row along `-n_v`
/// with free gap `g`. Frictionless: the skull pushes along `-n_v` only, so
/// the tissue slides along it. Nodes in an open region (the craniotomy
/// window) and fixed nodes have no row.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SkullSurface {
    /// CSF gap `g`, m (> 0).
    pub csf_gap_m: f64,
    /// The supported surface nodes: volume node and unit outward rest normal.
    pub nodes: Vec<(u32, Vector3<f64>)>,
}

impl SkullSurface {
    /// The gap of node `k` (an index into [`Self::nodes`]) at displacement
    /// `u`, m: `g - n . u` (negative: the node is beyond the skull).
    #[inline]
    pub fn gap_m(&self, k: usize, u: &Vector3<f64>) -> f64 {
        self.csf_gap_m - self.nodes[k].1.dot(u)
    }
}

#[derive(Debug, Clone, Copy)]
struct Active {
    node: u32,
    normal: Vector3<f64>,
    value: f64,
    containing: bool,
}

/// A strategy wrapped with the skull's unilateral constraints.
pub struct SkullSolver {
    inner: Box<dyn DeformationSolver>,
    skull: Skull,
    rest: Vec<Point3<f64>>,
    candidates: Vec<u32>,
    active: Vec<Active>,
    active_before: Vec<Active>,
    cons: Vec<Constraint>,
    in_step: Vec<bool>,
    solution: Solution,
    /// Most active-set rounds per step.
    pub max_rounds: u32,
    /// Nodes held by the skull after the last step.
    pub skull_nodes: Vec<u32>,
}

impl SkullSolver {
    /// Wraps `inner`; `rest` are the rest positions and `candidates` the
    /// nodes the skull may touch (the surface). Fails on a non-positive radius.
    pub fn new(
        inner: Box<dyn DeformationSolver>,
        skull: Skull,
        rest: Vec<Point3<f64>>,
        candidates: Vec<u32>,
    ) -> Result<Self, SolveError> {
        for s in [skull.containing, skull.excluding].into_iter().flatten() {
            if !(s.radius > 0.0
                && s.radius.is_finite()
                && s.centre.coords.iter().all(|c| c.is_finite()))
            {
                return Err(SolveError::InvalidModel(format!(
                    "skull sphere of radius {} m",
                    s.radius
                )));
            }
        }
        let n = rest.len();
        Ok(Self {
            inner,
            skull,
            rest,
            candidates,
            active: Vec::new(),
            active_before: Vec::new(),
            cons: Vec::new(),
            in_step: vec![false; n],
            solution: Solution::default(),
            max_rounds: 30,
            skull_nodes: Vec::new(),
        })
    }

    fn step(&mut self, user: &[Constraint]) -> Result<&Solution, SolveError> {
        for c in user {
            if let Some(f) = self.in_step.get_mut(c.node as usize) {
                *f = true;
            }
        }
        let in_step = std::mem::take(&mut self.in_step);
        self.active_before.clone_from(&self.active);
        let result = self.rounds(user, &in_step);
        if result.is_err() {
            // The last good state includes its active set.
            std::mem::swap(&mut self.active, &mut self.active_before);
        }
        self.in_step = in_step;
        for c in user {
            if let Some(f) = self.in_step.get_mut(c.node as usize) {
                *f = false;
            }
        }
        result?;
        Ok(&self.solution)
    }

    fn radial(
        rest: &[Point3<f64>],
        node: u32,
        u: Vector3<f64>,
        s: &Sphere,
    ) -> (Vector3<f64>, f64, f64) {
        let x = rest[node as usize];
        let d = x + u - s.centre;
        let dist = d.norm();
        let n = if dist > 0.0 { d / dist } else { Vector3::z() };
        (n, s.radius - n.dot(&(x - s.centre)), dist)
    }

    fn rounds(&mut self, user: &[Constraint], in_step: &[bool]) -> Result<(), SolveError> {
        if user.is_empty() {
            // A reset: start the active set afresh.
            self.active.clear();
        }
        self.active.retain(|a| !in_step[a.node as usize]);
        let nu = user.len();
        for _ in 0..self.max_rounds {
            self.cons.clear();
            self.cons.extend_from_slice(user);
            for a in &self.active {
                self.cons.push(Constraint {
                    node: a.node,
                    kind: ConstraintKind::Normal {
                        normal: a.normal,
                        displacement: a.value,
                    },
                });
            }
            let sol = self.inner.solve_constraints(&self.cons)?;
            let mut changed = false;
            // Release pulling nodes.
            let before = self.active.len();
            let mut k = 0;
            self.active.retain(|a| {
                let lam = sol.reactions[nu + k].dot(&a.normal);
                k += 1;
                if a.containing { lam <= 0.0 } else { lam >= 0.0 }
            });
            changed |= self.active.len() != before;
            // Add violating nodes.
            for &n in &self.candidates {
                if in_step[n as usize] || self.active.iter().any(|a| a.node == n) {
                    continue;
                }
                let u = sol.displacements[n as usize];
                for (sphere, containing) in
                    [(self.skull.containing, true), (self.skull.excluding, false)]
                {
                    let Some(s) = sphere else { continue };
                    let (normal, value, dist) = Self::radial(&self.rest, n, u, &s);
                    let violated = if containing {
                        dist > s.radius * (1.0 + 1e-9)
                    } else {
                        dist < s.radius * (1.0 - 1e-9)
                    };
                    if violated {
                        self.active.push(Active {
                            node: n,
                            normal,
                            value,
                            containing,
                        });
                        changed = true;
                        break;
                    }
                }
            }
            if !changed {
                self.solution.displacements.clone_from(&sol.displacements);
                self.solution.reactions.clear();
                self.solution
                    .reactions
                    .extend_from_slice(&sol.reactions[..nu]);
                self.solution.iterations = sol.iterations;
                self.skull_nodes.clear();
                self.skull_nodes.extend(self.active.iter().map(|a| a.node));
                return Ok(());
            }
        }
        Err(SolveError::NotConverged {
            iterations: self.max_rounds,
            residual: f64::NAN,
        })
    }
}

impl DeformationSolver for SkullSolver {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn solve(&mut self, prescribed: &[Prescribed]) -> Result<&Solution, SolveError> {
        let user: Vec<Constraint> = prescribed.iter().map(Constraint::from).collect();
        self.step(&user)
    }

    fn solve_constraints(&mut self, constraints: &[Constraint]) -> Result<&Solution, SolveError> {
        self.step(constraints)
    }

    fn local_model(&self) -> Option<&LocalModel> {
        self.inner.local_model()
    }

    fn support_reactions(&self) -> &[Vector3<f64>] {
        self.inner.support_reactions()
    }

    fn node_count(&self) -> usize {
        self.inner.node_count()
    }

    fn cache_bytes(&self) -> usize {
        self.inner.cache_bytes()
    }

    fn set_tie_springs(&mut self, springs: &super::ties::TieSprings) -> bool {
        self.inner.set_tie_springs(springs)
    }

    fn last_solution(&self) -> Option<&Solution> {
        Some(&self.solution)
    }
}
