//! Deformation of the brain model, DESIGN.md section 3: P1 tetrahedra, SI units
//! (m, Pa, N), f64, static equilibrium under fixed nodes and enforced
//! displacements (Dirichlet conditions from the collision stage).
//!
//! Sign convention: the *reaction* at a constrained node is the force the
//! constraint applies to the tissue there (N), equal to `(K u)` at that node's
//! DOFs for linear elasticity. The force of the tissue on an instrument is minus
//! the sum of the reactions at the nodes it displaces.

/// Implements [`DeformationSolver`] for a strategy that answers full and
/// general constraints alike by one inherent `step` (generic over
/// `Into<Constraint>`), keeps its last `solution` and its
/// `support_reactions`, and has no local model: `$name` is its scene-file
/// name, `[$($model)+]` the path from `self` to its [`model::Model`] (what
/// answers `n_nodes()`); the strategy's other trait items follow.
macro_rules! stepping_solver {
    ($ty:ty, $name:expr, [$($model:tt)+] $($extra:tt)*) => {
        impl $crate::fem::DeformationSolver for $ty {
            fn name(&self) -> &'static str {
                $name
            }

            fn solve(
                &mut self,
                prescribed: &[$crate::fem::Prescribed],
            ) -> Result<&$crate::fem::Solution, $crate::fem::SolveError> {
                self.step(prescribed)
            }

            fn solve_constraints(
                &mut self,
                constraints: &[$crate::fem::Constraint],
            ) -> Result<&$crate::fem::Solution, $crate::fem::SolveError> {
                self.step(constraints)
            }

            fn local_model(&self) -> Option<&$crate::fem::LocalModel> {
                None
            }

            fn support_reactions(&self) -> &[nalgebra::Vector3<f64>] {
                &self.support_reactions
            }

            fn node_count(&self) -> usize {
                self.$($model)+.n_nodes()
            }

            fn last_solution(&self) -> Option<&$crate::fem::Solution> {
                Some(&self.solution)
            }

            $($extra)*
        }
    };
}

pub mod assembly;
pub mod column_queue;
pub mod compliance;
pub mod constraint;
pub mod contact;
pub mod corotational;
pub mod direct;
pub mod element;
pub mod factor;
pub mod foundation;
pub mod held_normals;
pub mod lcp;
pub mod model;
pub mod neo_hookean;
pub mod nodal_pressure;
pub mod par;
pub mod reactions;
pub mod roi;
pub mod skull;
pub mod tangent;
pub mod ties;

pub use constraint::{Constraint, ConstraintKind};
pub use contact::{CompliancePatch, ContactAnswer, ContactRow, SharedBlocks};
pub use lcp::RowKind;
pub use model::AxisSupport;
pub use par::Par;

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

/// The material of one tissue: the elements whose mesh label is `label`
/// take it ([`model::Model::set_tissues`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tissue {
    /// The tissue's label in the mesh (`TetMesh::labels`).
    pub label: u32,
    /// Its material.
    pub material: Material,
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
    /// A matrix that must be symmetric positive definite is not: its
    /// Cholesky factorization met a non-positive pivot (`pivot`, when the
    /// factorization names it).
    #[error("{matrix} is not positive definite{}{hint}", pivot.map_or(String::new(), |p| format!(" (pivot {p} is not positive)")))]
    NotPositiveDefinite {
        /// Which matrix.
        matrix: &'static str,
        /// The pivot that failed.
        pivot: Option<usize>,
        /// What usually causes it here.
        hint: &'static str,
    },
    /// The sparse factorization's own resources failed (index overflow, out
    /// of memory).
    #[error("factorization of {matrix}: {source}")]
    Sparse {
        /// Which matrix.
        matrix: &'static str,
        /// What faer reported.
        #[source]
        source: faer::sparse::FaerError,
    },
    /// A least-norm solve of a singular system failed.
    #[error("{matrix}: {reason}")]
    Singular {
        /// Which system.
        matrix: &'static str,
        /// What the decomposition reported.
        reason: &'static str,
    },
    /// An iterative solve did not reach its tolerance.
    #[error("did not converge after {iterations} iterations (residual {residual:e})")]
    NotConverged { iterations: u32, residual: f64 },
    /// An element inverted (non-positive volume in the deformed state).
    #[error("element {element} inverted (J = {jacobian:e})")]
    Inverted { element: usize, jacobian: f64 },
    /// A node's volume inverted (non-positive `J_a`, the ratio of its
    /// deformed to its rest nodal volume, under the nonlinear
    /// average-nodal-pressure element, [`nodal_pressure::NodalVolumes`]).
    #[error("the volume of node {node} inverted (J = {jacobian:e})")]
    InvertedNode { node: usize, jacobian: f64 },
    /// The model cannot be built (material out of range, degenerate element).
    #[error("invalid model: {0}")]
    InvalidModel(String),
    /// The contact problem could not be solved.
    #[error(transparent)]
    Contact(#[from] lcp::LcpError),
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
    /// On error (a non-finite or bad input, no convergence, an inverted
    /// element) the previous solution stays available and no non-finite
    /// value is ever returned. An empty `prescribed` returns to rest (zero
    /// displacement) and clears every warm start.
    fn solve(&mut self, prescribed: &[Prescribed]) -> Result<&Solution, SolveError>;
    /// The local model of the last successful step, if the strategy has one.
    fn local_model(&self) -> Option<&LocalModel>;
    /// Solves under general constraints (full, normal-only, per-axis), see
    /// [`Constraint`]. Reactions come in the order of `constraints`. The
    /// default handles full constraints only, through [`Self::solve`].
    fn solve_constraints(&mut self, constraints: &[Constraint]) -> Result<&Solution, SolveError> {
        let mut prescribed = Vec::with_capacity(constraints.len());
        for c in constraints {
            match c.kind {
                ConstraintKind::Full(displacement) => prescribed.push(Prescribed {
                    node: c.node,
                    displacement,
                }),
                _ => {
                    return Err(SolveError::BadConstraint {
                        node: c.node,
                        reason: format!("strategy {} takes full constraints only", self.name()),
                    });
                }
            }
        }
        self.solve(&prescribed)
    }
    /// Reactions at the fixed nodes of the last successful step (N, the force
    /// the support applies to the tissue), in the order of the fixed list;
    /// empty where the strategy does not compute them.
    fn support_reactions(&self) -> &[Vector3<f64>] {
        &[]
    }
    /// The last successful solution (all zero before the first step), if kept.
    fn last_solution(&self) -> Option<&Solution> {
        None
    }
    /// Number of volume nodes of the model.
    fn node_count(&self) -> usize;
    /// Solves the contact problem `rows` ([`contact`]): unilateral,
    /// bilateral and (strategies with a compliance operator) frictional
    /// rows. On return [`Self::last_solution`] holds the displacements and
    /// `answer` the multipliers. The default runs rounds of
    /// [`Self::solve_constraints`] ([`contact::solve_by_active_set`]). On
    /// error the previous solution stays.
    fn solve_contact(
        &mut self,
        rows: &[ContactRow],
        answer: &mut ContactAnswer,
    ) -> Result<(), SolveError> {
        let n = self.node_count();
        contact::solve_by_active_set(self, rows, n, answer)
    }
    /// Fills `patch` with the compliance blocks over `nodes` (those whose
    /// compliance is available; see [`CompliancePatch`]) for the force
    /// loop's local contact problem. `false` (the default) when the
    /// strategy has no compliance operator.
    fn compliance_patch(&mut self, _nodes: &[u32], _patch: &mut CompliancePatch) -> bool {
        false
    }
    /// Strategies that hold the ties as springs of their own energy (the
    /// nonlinear ones, [`ties::TieSprings`]) take the intact pairs here and
    /// answer `true`: the next steps and local models have them, and the
    /// contact rows carry no tie. `false` (the default): the strategy takes
    /// ties as contact rows ([`ties::TieRows`]). Each pair's index is among
    /// [`SolverOptions::tie_pairs`].
    fn set_tie_springs(&mut self, _springs: &ties::TieSprings) -> bool {
        false
    }
    /// Declares nodes that every later patch holds (the ties' nodes): a
    /// strategy whose compliance never changes computes their blocks among
    /// themselves once and shares them ([`contact::SharedBlocks`]). The
    /// default ignores it.
    fn share_patch_nodes(&mut self, _nodes: &[u32]) {}
    /// Asks for the compliance of `nodes` ahead of their contact (computed
    /// in the background where the strategy defers it). The default does
    /// nothing.
    fn prefetch(&mut self, _nodes: &[u32]) {}
    /// Computes once and holds the compliance of `nodes` along their unit
    /// directions (the skull surface's supported nodes and rest normals,
    /// [`held_normals`]), so that contact rows along them need no
    /// compliance column in a step or a patch. `Ok(false)` (the default):
    /// the strategy does not hold any.
    fn hold_normals(&mut self, _nodes: &[(u32, Vector3<f64>)]) -> Result<bool, SolveError> {
        Ok(false)
    }
    /// Bytes of what [`Self::hold_normals`] holds (never evicted; not in
    /// [`Self::cache_bytes`]). The default is 0.
    fn held_bytes(&self) -> usize {
        0
    }
    /// Nodes whose compliance columns the strategy solved since it was
    /// built (0 where it has none).
    fn columns_solved(&self) -> u64 {
        0
    }
    /// Bytes the strategy holds in caches that grow with use (the
    /// compliance columns of the nodes contact has reached), so that memory
    /// growth from them can be told from any other. The default is 0.
    fn cache_bytes(&self) -> usize {
        0
    }
    /// Whether [`Self::solve_loaded`] and [`Self::load_response`] work.
    fn takes_loads(&self) -> bool {
        false
    }
    /// Linear strategies that factor their constrained system: solves under
    /// `constraints` with nodal loads `loads` (N) too. The default refuses.
    fn solve_loaded(
        &mut self,
        _constraints: &[Constraint],
        _loads: &[(u32, Vector3<f64>)],
    ) -> Result<&Solution, SolveError> {
        Err(SolveError::InvalidModel(format!(
            "strategy {} takes no nodal loads",
            self.name()
        )))
    }
    /// Linear strategies that keep the factor of their last solve: the
    /// displacement of every node (m) and the constraints' reactions (N)
    /// under `loads` (N) with the last solve's constraints held at zero.
    /// `false` (the default) when the strategy cannot.
    fn load_response(
        &mut self,
        _loads: &[(u32, Vector3<f64>)],
        _u: &mut Vec<Vector3<f64>>,
        _reactions: &mut Vec<Vector3<f64>>,
    ) -> bool {
        false
    }
    /// How contact solves and patches get compliance they lack
    /// ([`compliance::ColumnPolicy`]); `hook` runs first on a background
    /// thread, if one is started. Ignored by strategies without a
    /// compliance operator.
    fn set_column_policy(
        &mut self,
        _policy: compliance::ColumnPolicy,
        _hook: Option<std::sync::Arc<dyn Fn() + Send + Sync>>,
    ) {
    }
}

/// The solver strategies, named as in scene files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Strategy {
    /// Eliminate and factor every step (exact reference).
    Direct,
    /// Factor once, condense onto the contact DOFs (exact, fast; default).
    #[default]
    Compliance,
    /// Corotational linear elasticity (large rotation, small strain).
    Corotational,
    /// Compressible neo-Hookean, Newton (accuracy reference).
    NeoHookean,
}

impl Strategy {
    /// All strategies.
    pub const ALL: [Strategy; 4] = [
        Self::Direct,
        Self::Compliance,
        Self::Corotational,
        Self::NeoHookean,
    ];

    /// What the strategy's own file declares of it (the one place a
    /// strategy is registered besides its variant).
    pub fn kind(self) -> &'static StrategyKind {
        match self {
            Self::Direct => &direct::KIND,
            Self::Compliance => &compliance::KIND,
            Self::Corotational => &corotational::KIND,
            Self::NeoHookean => &neo_hookean::KIND,
        }
    }

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        self.kind().name
    }

    /// Whether it builds the element `element`: every strategy takes
    /// `tet4`; the nodal-pressure element is written for energies the
    /// strategy evaluates itself (the linear stiffness, the neo-Hookean
    /// energy), so `corotational`, whose force is a rotated linear stress
    /// per element with no nodal part, does not take it.
    pub fn takes_element(self, element: Element) -> bool {
        element == Element::Tet4 || self != Self::Corotational
    }

    /// Whether its elasticity is linear (small strain about the rest
    /// shape): its compliance is constant, so its stiffness (an elastic
    /// foundation folded in) is factored once and its contact linearized
    /// about the rest shape.
    pub fn is_linear(self) -> bool {
        self.kind().linear
    }
}

/// What the engine, the service and the study know of a solver strategy,
/// declared as a `KIND` constant beside the strategy's solver in its own
/// file. A new strategy is its file (the solver, its
/// [`DeformationSolver`] implementation and its `KIND`) plus its
/// [`Strategy`] variant with the arm of [`Strategy::kind`]; the scene's
/// checks, the service's `Material.model` and the study's labels read the
/// kind, so nothing else changes.
#[derive(Debug)]
pub struct StrategyKind {
    /// The scene-file name (`solver.strategy`).
    pub name: &'static str,
    /// The short label of the study's configurations.
    pub label: &'static str,
    /// Linear elasticity about the rest shape ([`Strategy::is_linear`]).
    pub linear: bool,
    /// The constitutive law reported as `SceneDescription.material.model`:
    /// the linear strategies share `linear`, a nonlinear one names its own.
    pub material_model: &'static str,
    /// Builds the solver on `model` (fixed nodes, tissues, element and
    /// foundation already applied by [`build_solver`]).
    pub build: BuildSolver,
}

/// How a [`StrategyKind`] builds its solver.
pub type BuildSolver =
    fn(model::Model, &SolverOptions) -> Result<Box<dyn DeformationSolver>, SolveError>;

impl std::str::FromStr for Strategy {
    type Err = SolveError;
    fn from_str(s: &str) -> Result<Self, SolveError> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|k| k.name()).collect();
                SolveError::InvalidModel(format!("unknown strategy {s:?} ({})", names.join(", ")))
            })
    }
}

/// The element formulation on the 4-node tetrahedral mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Element {
    /// Linear tetrahedra, one point (P1; locks as `nu -> 0.5`).
    #[default]
    Tet4,
    /// Linear tetrahedra with the volumetric strain averaged over each
    /// node's star ([`nodal_pressure`], Bonet and Burton 1998): locking-free
    /// near incompressibility, a wider stiffness pattern. The linear
    /// strategies (`direct`, `compliance`) take the linear element,
    /// `neo-hookean` its nonlinear analogue (the nodal volume ratio,
    /// [`nodal_pressure::NodalVolumes`]); `corotational` refuses it.
    Tet4NodalPressure,
}

impl Element {
    /// All formulations.
    pub const ALL: [Element; 2] = [Self::Tet4, Self::Tet4NodalPressure];

    /// The scene-file name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Tet4 => "tet4",
            Self::Tet4NodalPressure => "tet4-nodal-pressure",
        }
    }
}

impl std::str::FromStr for Element {
    type Err = SolveError;
    fn from_str(s: &str) -> Result<Self, SolveError> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|k| k.name()).collect();
                SolveError::InvalidModel(format!("unknown element {s:?} ({})", names.join(", ")))
            })
    }
}

/// Options of [`build_solver`].
#[derive(Debug, Clone)]
pub struct SolverOptions {
    /// Which nodes `compliance` recovers (default: all).
    pub recover: compliance::Recover,
    /// Per-axis supports (rollers) in addition to the fixed nodes.
    pub axis_supports: Vec<AxisSupport>,
    /// Tolerances of `corotational` and `neo-hookean`.
    pub iterative: corotational::IterativeOptions,
    /// The skull spheres, when the scene asks for them (wraps the strategy
    /// in an active set over the surface nodes).
    pub skull: Option<skull::Skull>,
    /// An elastic foundation on the outer surface ([`foundation`]): its
    /// springs are folded into the element matrices once (the linear
    /// strategies' stiffness) and kept apart for the nonlinear ones, which
    /// add their force, tangent and energy to the tissue's
    /// ([`model::Model::foundation`]). Every strategy takes it.
    pub foundation: Option<foundation::Foundation>,
    /// Parallelism of the per-element loops (`corotational`) and of the
    /// dense block factorization and recovery (`compliance`,
    /// `corotational`); the answers do not depend on it beyond round-off.
    /// Default `Par::rayon(0)`: every thread of the current rayon pool; a
    /// caller sharing the cores with a latency-critical loop may prefer
    /// `Par::Seq` or `Par::rayon(n)`.
    pub parallelism: Par,
    /// Bound of the `K0^-1` column cache of `compliance` and
    /// `corotational`, in contact nodes (least recently used evicted);
    /// `None`: [`compliance::DEFAULT_CACHE_BYTES`] worth of columns.
    pub cache_nodes: Option<usize>,
    /// The element formulation (default [`Element::Tet4`]).
    pub element: Element,
    /// The node pairs the scene's ties join ([`ties::TieRows`] with every
    /// tie intact): `corotational` and `neo-hookean` couple them in their
    /// sparsity pattern and hold the intact ones as springs of their energy
    /// ([`DeformationSolver::set_tie_springs`]); the linear strategies take
    /// ties as contact rows and ignore it.
    pub tie_pairs: Vec<[u32; 2]>,
    /// A material per tissue label (elements of other labels, and every
    /// element of an unlabelled mesh, take the `material` argument of
    /// [`build_solver`]). Every strategy and element honours it.
    pub tissues: Vec<Tissue>,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            recover: compliance::Recover::default(),
            axis_supports: Vec::new(),
            iterative: corotational::IterativeOptions::default(),
            skull: None,
            foundation: None,
            parallelism: par::default_par(),
            cache_nodes: None,
            element: Element::default(),
            tie_pairs: Vec::new(),
            tissues: Vec::new(),
        }
    }
}

/// Builds a deformation solver for `mesh` (positions in m) with `material`,
/// nodes `fixed` held in place, and the chosen `strategy`. Factorizations a
/// strategy needs once per scene happen here. Every strategy takes an
/// elastic foundation ([`SolverOptions::foundation`]); the nodal-pressure
/// element is refused with `corotational` only.
pub fn build_solver(
    strategy: Strategy,
    mesh: &crate::mesh::TetMesh,
    material: Material,
    fixed: &[u32],
    options: &SolverOptions,
) -> Result<Box<dyn DeformationSolver>, SolveError> {
    let mut model = model::Model::new(mesh, material, fixed, &options.axis_supports)?;
    model.set_tissues(&mesh.labels, material, &options.tissues)?;
    if options.element == Element::Tet4NodalPressure {
        if !strategy.takes_element(options.element) {
            return Err(SolveError::InvalidModel(format!(
                "element {} needs the direct, compliance or neo-hookean strategy, not {}",
                options.element.name(),
                strategy.name()
            )));
        }
        model.use_nodal_pressure();
    }
    if let Some(f) = &options.foundation {
        foundation::fold_into(&mut model, f)?;
    }
    if !strategy.is_linear() && !options.tie_pairs.is_empty() {
        model.couple_pairs(&options.tie_pairs)?;
    }
    let solver = (strategy.kind().build)(model, options)?;
    match options.skull {
        None => Ok(solver),
        Some(s) => {
            let candidates = mesh.boundary().to_volume;
            Ok(Box::new(skull::SkullSolver::new(
                solver,
                s,
                mesh.nodes.clone(),
                candidates,
            )?))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    /// Each strategy is what its kind says: the scene name reads back to it,
    /// the solver built for it reports that name, and no two strategies
    /// share a name or a study label.
    #[test]
    fn each_strategy_builds_the_solver_its_kind_names() {
        let mesh = cube(0.01, 2);
        let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
            .filter(|&n| mesh.nodes[n as usize].z < 1e-12)
            .collect();
        let material = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: 0.45,
        };
        for s in Strategy::ALL {
            let kind = s.kind();
            assert_eq!(kind.name.parse::<Strategy>().unwrap(), s);
            let solver =
                build_solver(s, &mesh, material, &fixed, &SolverOptions::default()).unwrap();
            assert_eq!(solver.name(), kind.name, "{s:?}");
            for t in Strategy::ALL.into_iter().filter(|&t| t != s) {
                assert_ne!(t.kind().name, kind.name);
                assert_ne!(t.kind().label, kind.label);
            }
        }
    }
}
