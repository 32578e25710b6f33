//! The discretised model shared by every strategy: rest geometry, element
//! stiffnesses, the sparsity pattern and the fixed supports.

use super::assembly::Pattern;
use super::element::{ElementMatrix, TetGeometry};
use super::foundation::FoundationSprings;
use super::nodal_pressure::NodalPressure;
use super::{Material, SolveError, Tissue};
use crate::mesh::TetMesh;
use nalgebra::Point3;

/// A per-axis support: DOF `axis` (0, 1, 2) of `node` held at zero (a roller
/// when alone, part of a fixed node when all three are held).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisSupport {
    /// Volume node.
    pub node: u32,
    /// Axis 0, 1, 2 = x, y, z.
    pub axis: u8,
}

/// Rest-state model of a mesh under fixed supports.
#[derive(Debug, Clone)]
pub struct Model {
    /// Tetrahedra (node indices).
    pub tets: Vec<[u32; 4]>,
    /// Rest positions, m.
    pub rest: Vec<Point3<f64>>,
    /// Rest geometry per element.
    pub geoms: Vec<TetGeometry>,
    /// Linear element stiffness per element, N/m (with the springs of an
    /// elastic foundation on its outer faces, once
    /// [`super::foundation::fold_into`] has added them): the rest stiffness.
    pub kel: Vec<ElementMatrix>,
    /// The springs of an elastic foundation apart from `kel` (which holds
    /// them too), for the nonlinear strategies, whose internal force and
    /// tangent come from the stress and add these ([`super::foundation`]);
    /// empty without a foundation.
    pub foundation: FoundationSprings,
    /// Lamé parameters `[lambda, mu]` per element, Pa (one material, or
    /// each element its tissue's, [`Model::set_tissues`]).
    pub lame_pa: Vec<[f64; 2]>,
    /// Sparsity pattern of the global stiffness.
    pub pattern: Pattern,
    /// Held DOFs (supports), per DOF.
    pub support: Vec<bool>,
    /// Fully fixed nodes in the order given (support reactions use it).
    pub fixed: Vec<u32>,
    /// The largest Young's modulus of the elements, Pa (scales the
    /// convergence floor, [`Model::force_floor`]).
    pub youngs_modulus_pa: f64,
    /// Characteristic length: the diagonal of the rest bounding box, m.
    pub length_m: f64,
    /// The volumetric part on the nodes, when the model uses the
    /// average-nodal-pressure element ([`Model::use_nodal_pressure`]); `kel`
    /// is then the deviatoric part alone (and `neo-hookean` gives its
    /// elements `lambda = -2 mu / 3`, [`super::nodal_pressure::NodalVolumes`]).
    pub pressure: Option<NodalPressure>,
}

impl Model {
    /// Builds the model. `fixed` nodes are held in all three DOFs, `axis`
    /// supports in one; nodes in no element are held too (they carry no
    /// stiffness). Fails on a bad material, a fixed index out of range or a
    /// degenerate element (named by index).
    pub fn new(
        mesh: &TetMesh,
        material: Material,
        fixed: &[u32],
        axis: &[AxisSupport],
    ) -> Result<Self, SolveError> {
        check_material(&material, "")?;
        let e = material.youngs_modulus_pa;
        let (lambda, mu) = material.lame();
        let n_nodes = mesh.nodes.len();
        let mut geoms = Vec::with_capacity(mesh.tets.len());
        let mut used = vec![false; n_nodes];
        for (i, t) in mesh.tets.iter().enumerate() {
            if let Some(&n) = t.iter().find(|&&n| n as usize >= n_nodes) {
                return Err(SolveError::InvalidModel(format!(
                    "element {i} refers to node {n} of {n_nodes}"
                )));
            }
            let g = TetGeometry::new(t.map(|n| mesh.nodes[n as usize])).ok_or_else(|| {
                SolveError::InvalidModel(format!("element {i} is degenerate or inverted at rest"))
            })?;
            geoms.push(g);
            for &n in t {
                used[n as usize] = true;
            }
        }
        let mut support = vec![false; 3 * n_nodes];
        for &n in fixed {
            if n as usize >= n_nodes {
                return Err(SolveError::BadConstraint {
                    node: n,
                    reason: "fixed node out of range".into(),
                });
            }
            support[3 * n as usize..3 * n as usize + 3].fill(true);
        }
        for s in axis {
            if s.node as usize >= n_nodes || s.axis > 2 {
                return Err(SolveError::BadConstraint {
                    node: s.node,
                    reason: format!("bad axis support (axis {})", s.axis),
                });
            }
            support[3 * s.node as usize + s.axis as usize] = true;
        }
        for (n, u) in used.iter().enumerate() {
            if !u {
                support[3 * n..3 * n + 3].fill(true);
            }
        }
        let kel = geoms.iter().map(|g| g.stiffness(lambda, mu)).collect();
        let pattern = Pattern::new(n_nodes, &mesh.tets);
        let length_m = if n_nodes == 0 {
            0.0
        } else {
            let (lo, hi) = mesh.bounds();
            (hi - lo).norm()
        };
        Ok(Self {
            tets: mesh.tets.clone(),
            rest: mesh.nodes.clone(),
            lame_pa: vec![[lambda, mu]; geoms.len()],
            geoms,
            kel,
            foundation: FoundationSprings::default(),
            pattern,
            support,
            fixed: fixed.to_vec(),
            youngs_modulus_pa: e,
            length_m,
            pressure: None,
        })
    }

    /// Gives each element its tissue's material: element `i` with label
    /// `labels[i]` takes the [`Tissue`] of that label, or `default` when no
    /// tissue names it (`labels` parallel to the elements). Call right after
    /// [`Model::new`], before [`Model::use_nodal_pressure`] and a
    /// foundation. Fails on a bad material (named by label), a label given
    /// twice, a tissue whose label is on no element, or tissues for a model
    /// without labels.
    pub fn set_tissues(
        &mut self,
        labels: &[u32],
        default: Material,
        tissues: &[Tissue],
    ) -> Result<(), SolveError> {
        if tissues.is_empty() {
            return Ok(());
        }
        if labels.len() != self.tets.len() {
            return Err(SolveError::InvalidModel(format!(
                "materials per tissue need a label per element: the model has {} labels \
                 for {} elements",
                labels.len(),
                self.tets.len()
            )));
        }
        let mut by_label = std::collections::HashMap::new();
        for t in tissues {
            check_material(&t.material, &format!("tissue label {}: ", t.label))?;
            if by_label.insert(t.label, t.material).is_some() {
                return Err(SolveError::InvalidModel(format!(
                    "tissue label {} is given twice",
                    t.label
                )));
            }
        }
        let mut used = std::collections::HashSet::new();
        let mut e_max: f64 = 0.0;
        for (i, &l) in labels.iter().enumerate() {
            let m = by_label.get(&l).copied().unwrap_or(default);
            used.insert(l);
            e_max = e_max.max(m.youngs_modulus_pa);
            let (lambda, mu) = m.lame();
            if self.lame_pa[i] == [lambda, mu] {
                // Built with this material already (`Model::new`'s).
                continue;
            }
            self.lame_pa[i] = [lambda, mu];
            self.kel[i] = self.geoms[i].stiffness(lambda, mu);
        }
        if let Some(t) = tissues.iter().find(|t| !used.contains(&t.label)) {
            return Err(SolveError::InvalidModel(format!(
                "tissue label {} is on no element of the model",
                t.label
            )));
        }
        self.youngs_modulus_pa = e_max;
        Ok(())
    }

    /// Switches to the average-nodal-pressure element
    /// ([`super::nodal_pressure`]): the element matrices keep the deviatoric
    /// part (`lambda = -2 mu / 3`), the volumetric part `kappa = lambda +
    /// 2 mu / 3` moves to the nodes, and the pattern widens to the nodes'
    /// stars. Call before folding a foundation into `kel`.
    pub fn use_nodal_pressure(&mut self) {
        let kappa: Vec<f64> = self
            .lame_pa
            .iter()
            .map(|&[lambda, mu]| lambda + 2.0 * mu / 3.0)
            .collect();
        for ((k, g), &[_, mu]) in self.kel.iter_mut().zip(&self.geoms).zip(&self.lame_pa) {
            *k = g.stiffness(-2.0 * mu / 3.0, mu);
        }
        let p = NodalPressure::new(self.n_nodes(), &self.tets, &self.geoms, &kappa);
        self.pattern = Pattern::with_groups(self.n_nodes(), &self.tets, p.stars());
        self.pressure = Some(p);
    }

    /// Couples each node pair of `pairs` in the pattern (pair `i` is the
    /// pseudo-element `tets.len() + i`, [`Pattern::with_pairs`]): the ties
    /// a nonlinear strategy holds as springs of its energy
    /// ([`super::ties::TieSprings`]). With the nodal-pressure element the
    /// pattern keeps the nodes' stars too.
    pub fn couple_pairs(&mut self, pairs: &[[u32; 2]]) -> Result<(), SolveError> {
        let n = self.n_nodes() as u32;
        if let Some(p) = pairs
            .iter()
            .find(|p| p[0] >= n || p[1] >= n || p[0] == p[1])
        {
            return Err(SolveError::InvalidModel(format!(
                "tie pair {p:?}: needs two distinct nodes below {n}"
            )));
        }
        self.pattern = match &self.pressure {
            None => Pattern::with_pairs(self.n_nodes(), &self.tets, pairs),
            Some(p) => Pattern::with_groups_and_pairs(self.n_nodes(), &self.tets, p.stars(), pairs),
        };
        Ok(())
    }

    /// Adds `K x` of the element matrices and the nodal volumetric part
    /// into `y` (DOF vectors; `y` is overwritten).
    pub fn matvec(&self, x: &[f64], y: &mut [f64]) {
        super::assembly::element_matvec(&self.tets, &self.kel, x, y);
        if let Some(p) = &self.pressure {
            p.add_matvec(x, y);
        }
    }

    /// The absolute force floor of the iterative strategies' convergence
    /// test, N: `strain x E x L^2` (`L` = [`Model::length_m`]), the force
    /// a uniform strain of `strain` produces over the model's size. See
    /// [`super::corotational::IterativeOptions::floor_strain`].
    pub fn force_floor(&self, strain: f64) -> f64 {
        strain * self.youngs_modulus_pa * self.length_m * self.length_m
    }

    /// Number of nodes.
    pub fn n_nodes(&self) -> usize {
        self.rest.len()
    }
}

/// Checks `E > 0` and `nu` in `[0, 0.5)`; `what` prefixes the message.
fn check_material(m: &Material, what: &str) -> Result<(), SolveError> {
    let (e, nu) = (m.youngs_modulus_pa, m.poisson_ratio);
    if !(e.is_finite() && e > 0.0) {
        return Err(SolveError::InvalidModel(format!(
            "{what}Young's modulus {e} Pa is not positive"
        )));
    }
    if !(nu.is_finite() && (0.0..0.5).contains(&nu)) {
        return Err(SolveError::InvalidModel(format!(
            "{what}Poisson ratio {nu} is not in [0, 0.5)"
        )));
    }
    Ok(())
}
