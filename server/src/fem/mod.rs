//! Deformation of the brain model, DESIGN.md section 3: P1 tetrahedra, SI units
//! (m, Pa, N), f64, static equilibrium under fixed nodes and enforced
//! displacements (Dirichlet conditions from the collision stage).
//!
//! Sign convention: the *reaction* at a constrained node is the force the
//! constraint applies to the tissue there (N), equal to `(K u)` at that node's
//! DOFs for linear elasticity. The force of the tissue on an instrument is minus
//! the sum of the reactions at the nodes it displaces.

use nalgebra::{DMatrix, Vector3};

/// Isotropic elastic material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Young's modulus E, Pa (> 0).
    pub youngs_modulus_pa: f64,
    /// Poisson's ratio nu, in [0, 0.5).
    pub poisson_ratio: f64,
}

impl Material {
    /// Lamé parameters (lambda, mu), Pa.
    pub fn lame(&self) -> (f64, f64) {
        let (e, nu) = (self.youngs_modulus_pa, self.poisson_ratio);
        let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = e / (2.0 * (1.0 + nu));
        (lambda, mu)
    }
}

/// An enforced displacement of one node (a Dirichlet condition on its 3 DOFs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prescribed {
    /// Volume node index.
    pub node: u32,
    /// Displacement from the rest position, m.
    pub displacement: Vector3<f64>,
}

/// Result of one deformation step.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Solution {
    /// Displacement of every node from rest, m.
    pub displacements: Vec<Vector3<f64>>,
    /// Reaction at each prescribed node, N, in the order of the `prescribed`
    /// slice given to [`DeformationSolver::solve`].
    pub reactions: Vec<Vector3<f64>>,
    /// Iterations the solver took (1 for direct solves).
    pub iterations: u32,
}

/// Why a deformation step failed. The solver keeps its last good state.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum SolveError {
    /// A prescribed node index is out of range or is also a fixed node.
    #[error("prescribed node {node}: {reason}")]
    BadConstraint { node: u32, reason: String },
    /// An input value is NaN or infinite.
    #[error("non-finite input: {0}")]
    NonFinite(String),
    /// The factorization failed (the stiffness is not positive definite).
    #[error("factorization failed: {0}")]
    Factorization(String),
    /// An iterative solve did not reach its tolerance.
    #[error("did not converge after {iterations} iterations (residual {residual:e})")]
    NotConverged { iterations: u32, residual: f64 },
    /// An element inverted (non-positive volume in the deformed state).
    #[error("element {element} inverted (J = {jacobian:e})")]
    Inverted { element: usize, jacobian: f64 },
}

/// The local model of the last deformation step, used by the force loop to
/// extrapolate reactions to new enforced displacements without a full solve:
/// `r(u) ~ r0 + S (u - u0)` on the contact DOFs, where `S` is the inverse of the
/// compliance block of those DOFs (their condensed stiffness).
#[derive(Debug, Clone, PartialEq)]
pub struct LocalModel {
    /// Volume nodes of the contact set, in block order.
    pub nodes: Vec<u32>,
    /// Compliance block `C = (K^-1)[c, c]`, 3m x 3m, m/N, DOF order
    /// (node0.x, node0.y, node0.z, node1.x, ...).
    pub compliance: DMatrix<f64>,
    /// Enforced displacements of the step, m, per node of `nodes`.
    pub displacements: Vec<Vector3<f64>>,
    /// Reactions of the step, N, per node of `nodes`.
    pub reactions: Vec<Vector3<f64>>,
}

/// A deformation solver strategy (`direct`, `compliance`, `corotational`,
/// `neo-hookean`). Fixed nodes are given at construction; each step gives the
/// enforced displacements.
pub trait DeformationSolver: Send {
    /// Strategy name as in scene files.
    fn name(&self) -> &'static str;
    /// Solves for static equilibrium under the fixed nodes and `prescribed`.
    /// On error the previous solution stays available.
    fn solve(&mut self, prescribed: &[Prescribed]) -> Result<&Solution, SolveError>;
    /// The local model of the last successful step, if the strategy has one.
    fn local_model(&self) -> Option<&LocalModel>;
}
