//! The force loop's local model: reactions at the contact DOFs extrapolated from
//! the last deformation step, without a full solve.
//!
//! The deformation step leaves, over its contact nodes `N` (all instruments),
//! the enforced displacements `u0`, the reactions `r0` and the condensed
//! stiffness `S = C^-1`, where `C = (K^-1)[N, N]` is the compliance block. For
//! linear elasticity with fixed supports `r = S u` exactly; in general
//! `r ~ r0 + S (u - u0)`.
//!
//! At a new pose, each node of `N` is either still constrained (`c`: its new
//! enforced displacement comes from the fresh collision query, or from the last
//! step for nodes of other instruments) or released (`f`: the instrument left
//! it, so its reaction must vanish). Eliminating the released DOFs gives
//!
//! ```text
//! x   = -S_ff^-1 (r0_f + S_fc du_c)        (free motion of released DOFs)
//! r_c =  r0_c + S_cc du_c + S_cf x
//! ```
//!
//! which costs `O(c^2 + c f + f^3)` per sample, with `f` small. Nodes the
//! query finds that are not in `N` (contact begun since the last step) have no
//! compliance columns yet; they are counted but add no force until the next
//! deformation step includes them.

use nalgebra::{DMatrix, DVector, Vector3};
use std::collections::HashMap;

/// The local model published with each snapshot.
#[derive(Debug, Clone, Default)]
pub struct ForceModel {
    /// Volume nodes of the contact set.
    pub nodes: Vec<u32>,
    /// Which instrument enforced each node's displacement.
    pub owner: Vec<u16>,
    /// Enforced displacements of the step, m.
    pub u0: Vec<Vector3<f64>>,
    /// Reactions of the step, N.
    pub r0: Vec<Vector3<f64>>,
    /// Rest positions of the nodes, m (for torques).
    pub rest: Vec<nalgebra::Point3<f64>>,
    /// Condensed stiffness `S`, 3m x 3m, N/m.
    pub stiffness: DMatrix<f64>,
    /// Node -> index in `nodes`.
    pub index: HashMap<u32, usize>,
    /// The frame that built it (identifies it for the force loop's caches).
    pub frame: u64,
}

/// Force and torque of the tissue on one instrument, and how many nodes it holds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct InstrumentForce {
    /// Force on the instrument, N.
    pub force: Vector3<f64>,
    /// Torque about the handle point, N m.
    pub torque: Vector3<f64>,
}

/// Reusable buffers of the force loop (no allocation once grown).
#[derive(Debug, Default)]
pub struct ForceWorkspace {
    constrained: Vec<usize>,
    released: Vec<usize>,
    du: Vec<Vector3<f64>>,
    /// Right-hand side, then the free motion `x` of the released DOFs.
    rhs: DVector<f64>,
    s_ff: DMatrix<f64>,
    /// Cholesky factor of `S_ff`, for the model of frame `factor_key` and
    /// the released set `factor_released`.
    factor: Option<nalgebra::Cholesky<f64, nalgebra::Dyn>>,
    factor_key: u64,
    factor_released: Vec<usize>,
}

impl ForceModel {
    /// Reactions on the nodes of `instrument`, given its fresh enforced
    /// displacements `fresh(node) -> Option<u>`, summed into force and torque
    /// about `handle` (m) on the instrument (minus the reactions).
    pub fn instrument_force(
        &self,
        instrument: u16,
        fresh: impl Fn(u32) -> Option<Vector3<f64>>,
        handle: &Vector3<f64>,
        ws: &mut ForceWorkspace,
    ) -> InstrumentForce {
        let m = self.nodes.len();
        if m == 0 {
            return InstrumentForce::default();
        }
        ws.constrained.clear();
        ws.released.clear();
        ws.du.clear();
        for i in 0..m {
            let du = if self.owner[i] == instrument {
                match fresh(self.nodes[i]) {
                    Some(u) => u - self.u0[i],
                    None => {
                        ws.released.push(i);
                        ws.du.push(Vector3::zeros());
                        continue;
                    }
                }
            } else {
                Vector3::zeros()
            };
            ws.constrained.push(i);
            ws.du.push(du);
        }
        let s = &self.stiffness;
        // x = -S_ff^-1 (r0_f + S_fc du_c)
        let nf = ws.released.len();
        if nf > 0 {
            // The factor of S_ff depends only on the model and the released
            // set: keep it while both stay the same (most samples between two
            // deformation steps), so a sample costs O(c f) here, not O(f^3).
            let key = self.frame;
            let cached =
                ws.factor.is_some() && ws.factor_key == key && ws.factor_released == ws.released;
            ws.rhs.resize_vertically_mut(3 * nf, 0.0);
            if !cached {
                ws.s_ff.resize_mut(3 * nf, 3 * nf, 0.0);
            }
            for (a, &fi) in ws.released.iter().enumerate() {
                for k in 0..3 {
                    let row = 3 * fi + k;
                    let mut v = self.r0[fi][k];
                    for &ci in &ws.constrained {
                        let du = &ws.du[ci];
                        for l in 0..3 {
                            v += s[(row, 3 * ci + l)] * du[l];
                        }
                    }
                    ws.rhs[3 * a + k] = -v;
                    if !cached {
                        for (b, &fj) in ws.released.iter().enumerate() {
                            for l in 0..3 {
                                ws.s_ff[(3 * a + k, 3 * b + l)] = s[(row, 3 * fj + l)];
                            }
                        }
                    }
                }
            }
            if !cached {
                // Factor in place and keep the buffer (no allocation once grown).
                let s_ff = std::mem::replace(&mut ws.s_ff, DMatrix::zeros(0, 0));
                ws.factor = s_ff.cholesky();
                ws.factor_key = key;
                ws.factor_released.clear();
                ws.factor_released.extend_from_slice(&ws.released);
            }
            match &ws.factor {
                Some(ch) => ch.solve_mut(&mut ws.rhs),
                None => ws.rhs.fill(0.0),
            }
        }
        let x = &ws.rhs;
        // r_c = r0_c + S_cc du_c + S_cf x, summed over this instrument's nodes.
        let mut out = InstrumentForce::default();
        for &ci in &ws.constrained {
            if self.owner[ci] != instrument {
                continue;
            }
            let mut r = self.r0[ci];
            for k in 0..3 {
                let row = 3 * ci + k;
                let mut v = 0.0;
                for &cj in &ws.constrained {
                    let du = &ws.du[cj];
                    for l in 0..3 {
                        v += s[(row, 3 * cj + l)] * du[l];
                    }
                }
                for (b, &fj) in ws.released.iter().enumerate() {
                    for l in 0..3 {
                        v += s[(row, 3 * fj + l)] * x[3 * b + l];
                    }
                }
                r[k] += v;
            }
            let p = self.rest[ci].coords + self.u0[ci] + ws.du[ci];
            out.force -= r;
            out.torque += (p - handle).cross(&(-r));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-node model with a known SPD stiffness; the local model must give
    /// r = S u for a linear model, and release a node exactly.
    #[test]
    fn linear_extrapolation_and_release() {
        let s = DMatrix::from_fn(6, 6, |i, j| {
            if i == j {
                4.0
            } else if i % 3 == j % 3 {
                1.0
            } else {
                0.0
            }
        });
        let u0 = vec![
            Vector3::new(0.0, 0.0, -0.001),
            Vector3::new(0.0, 0.0, -0.001),
        ];
        let uflat = DVector::from_iterator(6, u0.iter().flat_map(|u| u.iter().copied()));
        let r0f = &s * &uflat;
        let r0 = vec![
            Vector3::new(r0f[0], r0f[1], r0f[2]),
            Vector3::new(r0f[3], r0f[4], r0f[5]),
        ];
        let model = ForceModel {
            nodes: vec![10, 11],
            owner: vec![0, 0],
            u0: u0.clone(),
            r0: r0.clone(),
            rest: vec![nalgebra::Point3::origin(); 2],
            stiffness: s.clone(),
            index: [(10, 0), (11, 1)].into_iter().collect(),
            frame: 1,
        };
        let mut ws = ForceWorkspace::default();
        let h = Vector3::zeros();
        // Same displacements: the step's reactions.
        let f = model.instrument_force(0, |n| model.index.get(&n).map(|&i| u0[i]), &h, &mut ws);
        assert!((f.force + r0[0] + r0[1]).norm() < 1e-12);
        // Twice the push: twice the force (linear).
        let f2 = model.instrument_force(
            0,
            |n| model.index.get(&n).map(|&i| 2.0 * u0[i]),
            &h,
            &mut ws,
        );
        assert!((f2.force - 2.0 * f.force).norm() < 1e-12);
        // Node 11 released: the force equals the condensed one-node model
        // (S_cc - S_cf S_ff^-1 S_fc) u_c.
        let f1 = model.instrument_force(0, |n| (n == 10).then_some(u0[0]), &h, &mut ws);
        let scc = s.view((0, 0), (3, 3)).into_owned();
        let scf = s.view((0, 3), (3, 3)).into_owned();
        let sff = s.view((3, 3), (3, 3)).into_owned();
        let eff = &scc - &scf * sff.try_inverse().unwrap() * scf.transpose();
        let expect = -(eff * DVector::from_column_slice(u0[0].as_slice()));
        assert!((f1.force - Vector3::new(expect[0], expect[1], expect[2])).norm() < 1e-12);
        // Same released set again (the cached factor): still the condensed
        // model, now at twice the push.
        let f1b = model.instrument_force(0, |n| (n == 10).then_some(2.0 * u0[0]), &h, &mut ws);
        assert!((f1b.force - 2.0 * f1.force).norm() < 1e-12);
        // Other instruments' nodes contribute nothing to this one's force.
        let f_other = model.instrument_force(1, |_| None, &h, &mut ws);
        assert_eq!(f_other.force, Vector3::zeros());
    }
}
