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

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use nalgebra::{DMatrix, Vector3};
use std::collections::HashMap;

/// The local model published with each snapshot.
///
/// Built by [`ForceModel::new`], which keeps of the condensed stiffness only
/// one dense block per instrument (below); the public fields are for reading.
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
    /// Node -> index in `nodes`.
    pub index: HashMap<u32, usize>,
    /// The frame that built it (identifies it for the force loop's caches).
    pub frame: u64,
    /// Per instrument owning nodes: the block of `S` over its nodes.
    blocks: Vec<OwnerBlock>,
}

/// The rows and columns of `S` over one instrument's nodes `I`, symmetrised
/// (`(S + S^T) / 2`; `S = C^-1` is symmetric up to rounding), stored densely
/// so that row `p` is `s[p n .. (p + 1) n]`, `n = 3 |I|`.
///
/// A sample only ever needs this block: other instruments' nodes keep their
/// step displacements (`du = 0`) and are never released, so they add nothing
/// to `S_fc du_c` or `S_cc du_c` of this instrument's rows, and only this
/// instrument's reactions are summed. Reading a small contiguous block
/// instead of strided rows of the whole `S` is what keeps a sample at a few
/// microseconds with many contact nodes.
#[derive(Debug, Clone, Default)]
struct OwnerBlock {
    instrument: u16,
    /// Indices into [`ForceModel::nodes`] of the instrument's nodes.
    members: Vec<usize>,
    /// `3 |I| x 3 |I|`, row-major (equal to column-major: symmetric).
    s: Vec<f64>,
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
pub struct ForceWorkspace {
    /// Per member of the block: `Some(du)` constrained, `None` released.
    state: Vec<Option<Vector3<f64>>>,
    /// Block DOFs of the released members.
    released_dofs: Vec<usize>,
    /// `w`: `du` on constrained DOFs, the free motion `x` on released ones.
    w: Vec<f64>,
    /// Right-hand side, then the free motion `x` of the released DOFs.
    rhs: faer::Mat<f64>,
    /// Cholesky factor (lower) of `S_ff`, for the model of frame
    /// `factor_key`, instrument `factor_instrument` and the released DOFs
    /// `factor_released`.
    factor: faer::Mat<f64>,
    factor_ok: bool,
    factor_valid: bool,
    factor_key: u64,
    factor_instrument: u16,
    factor_released: Vec<usize>,
    scratch: Option<(usize, MemBuffer)>,
}

impl Default for ForceWorkspace {
    fn default() -> Self {
        Self {
            state: Vec::new(),
            released_dofs: Vec::new(),
            w: Vec::new(),
            rhs: faer::Mat::zeros(0, 1),
            factor: faer::Mat::zeros(0, 0),
            factor_ok: false,
            factor_valid: false,
            factor_key: 0,
            factor_instrument: 0,
            factor_released: Vec::new(),
            scratch: None,
        }
    }
}

impl std::fmt::Debug for ForceWorkspace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ForceWorkspace")
            .field("released_dofs", &self.released_dofs.len())
            .field("factor_valid", &self.factor_valid)
            .finish_non_exhaustive()
    }
}

/// `a . b` over equal lengths.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four partial sums: lets the compiler vectorise without reassociating
    // a single chain (the order is fixed, so results are reproducible).
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

impl ForceModel {
    /// A model over the contact nodes `nodes` (volume node indices), each
    /// enforced by instrument `owner[i]` (`u16::MAX`: none), with the step's
    /// enforced displacements `u0` (m), reactions `r0` (N) and condensed
    /// stiffness `stiffness` (`3m x 3m`, N/m). `rest` starts empty and
    /// `frame` at zero: the publisher fills them.
    pub fn new(
        nodes: Vec<u32>,
        owner: Vec<u16>,
        u0: Vec<Vector3<f64>>,
        r0: Vec<Vector3<f64>>,
        stiffness: &DMatrix<f64>,
    ) -> Self {
        let m = nodes.len();
        assert!(
            owner.len() == m
                && u0.len() == m
                && r0.len() == m
                && stiffness.nrows() == 3 * m
                && stiffness.ncols() == 3 * m,
            "inconsistent local model sizes"
        );
        let mut by_owner: Vec<(u16, Vec<usize>)> = Vec::new();
        for (i, &o) in owner.iter().enumerate() {
            if o == u16::MAX {
                continue;
            }
            match by_owner.iter_mut().find(|(k, _)| *k == o) {
                Some((_, v)) => v.push(i),
                None => by_owner.push((o, vec![i])),
            }
        }
        let blocks = by_owner
            .into_iter()
            .map(|(instrument, members)| {
                let n = 3 * members.len();
                let dof = |p: usize| 3 * members[p / 3] + p % 3;
                let mut s = vec![0.0; n * n];
                for q in 0..n {
                    let col = stiffness.column(dof(q));
                    for p in 0..n {
                        let sym = 0.5 * (col[dof(p)] + stiffness[(dof(q), dof(p))]);
                        s[p * n + q] = sym;
                    }
                }
                OwnerBlock {
                    instrument,
                    members,
                    s,
                }
            })
            .collect();
        Self {
            index: nodes.iter().enumerate().map(|(i, &n)| (n, i)).collect(),
            nodes,
            owner,
            u0,
            r0,
            rest: Vec::new(),
            frame: 0,
            blocks,
        }
    }

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
        let Some(block) = self.blocks.iter().find(|b| b.instrument == instrument) else {
            return InstrumentForce::default();
        };
        let n = 3 * block.members.len();
        let row = |p: usize| &block.s[p * n..(p + 1) * n];
        ws.state.clear();
        ws.released_dofs.clear();
        ws.w.clear();
        for (a, &i) in block.members.iter().enumerate() {
            let du = fresh(self.nodes[i]).map(|u| u - self.u0[i]);
            ws.state.push(du);
            match du {
                Some(du) => ws.w.extend_from_slice(du.as_slice()),
                None => {
                    ws.released_dofs.extend(3 * a..3 * a + 3);
                    ws.w.extend_from_slice(&[0.0; 3]);
                }
            }
        }
        // x = -S_ff^-1 (r0_f + S_fc du_c); `w` is zero on the released DOFs,
        // so a whole row of the block times `w` is `S_fc du_c`.
        let nf = ws.released_dofs.len();
        if nf > 0 {
            // The factor of S_ff depends only on the model, the instrument
            // and the released set: keep it while they stay the same (most
            // samples between two deformation steps).
            let cached = ws.factor_valid
                && ws.factor_key == self.frame
                && ws.factor_instrument == instrument
                && ws.factor_released == ws.released_dofs;
            if !cached {
                ws.factor.resize_with(nf, nf, |_, _| 0.0);
                for (a, &p) in ws.released_dofs.iter().enumerate() {
                    let r = row(p);
                    for (b, &q) in ws.released_dofs.iter().enumerate() {
                        ws.factor[(a, b)] = r[q];
                    }
                }
                let fits = matches!(&ws.scratch, Some((dim, _)) if *dim >= nf);
                if !fits {
                    let req = llt::factor::cholesky_in_place_scratch::<f64>(
                        nf,
                        faer::Par::Seq,
                        Default::default(),
                    );
                    ws.scratch = Some((nf, MemBuffer::new(req)));
                }
                let (_, mem) = ws.scratch.as_mut().expect("sized above");
                ws.factor_ok = llt::factor::cholesky_in_place(
                    ws.factor.as_mut(),
                    Default::default(),
                    faer::Par::Seq,
                    MemStack::new(mem),
                    Default::default(),
                )
                .is_ok();
                ws.factor_valid = true;
                ws.factor_key = self.frame;
                ws.factor_instrument = instrument;
                ws.factor_released.clone_from(&ws.released_dofs);
            }
            ws.rhs.resize_with(nf, 1, |_, _| 0.0);
            for (a, &p) in ws.released_dofs.iter().enumerate() {
                let i = block.members[p / 3];
                ws.rhs[(a, 0)] = -(self.r0[i][p % 3] + dot(row(p), &ws.w));
            }
            if ws.factor_ok {
                let (_, mem) = ws.scratch.as_mut().expect("sized above");
                llt::solve::solve_in_place(
                    ws.factor.as_ref(),
                    ws.rhs.as_mut(),
                    faer::Par::Seq,
                    MemStack::new(mem),
                );
            } else {
                // Not positive definite (a degenerate model): the released
                // DOFs do not move.
                ws.rhs.fill(0.0);
            }
            for (a, &p) in ws.released_dofs.iter().enumerate() {
                ws.w[p] = ws.rhs[(a, 0)];
            }
        }
        // r_c = r0_c + S_cc du_c + S_cf x = r0_c + (row of the block) . w,
        // summed over this instrument's constrained nodes.
        let mut out = InstrumentForce::default();
        for (a, &i) in block.members.iter().enumerate() {
            let Some(du) = ws.state[a] else {
                continue;
            };
            let mut r = self.r0[i];
            for k in 0..3 {
                r[k] += dot(row(3 * a + k), &ws.w);
            }
            let p = self.rest[i].coords + self.u0[i] + du;
            out.force -= r;
            out.torque += (p - handle).cross(&(-r));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

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
        let mut model = ForceModel::new(vec![10, 11], vec![0, 0], u0.clone(), r0.clone(), &s);
        model.rest = vec![nalgebra::Point3::origin(); 2];
        model.frame = 1;
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

    /// The reference: the local model's formulas over the whole contact set
    /// (every node of `N`, other instruments' nodes constrained with
    /// `du = 0`), with a dense inverse.
    fn reference(
        model: &ForceModel,
        s: &DMatrix<f64>,
        instrument: u16,
        fresh: &dyn Fn(u32) -> Option<Vector3<f64>>,
        handle: &Vector3<f64>,
    ) -> InstrumentForce {
        let m = model.nodes.len();
        let mut du = DVector::zeros(3 * m);
        let (mut c, mut f) = (Vec::new(), Vec::new());
        for i in 0..m {
            let mine = model.owner[i] == instrument;
            match (mine, fresh(model.nodes[i])) {
                (true, None) => f.extend(3 * i..3 * i + 3),
                (true, Some(u)) => {
                    du.rows_mut(3 * i, 3).copy_from(&(u - model.u0[i]));
                    c.extend(3 * i..3 * i + 3);
                }
                (false, _) => c.extend(3 * i..3 * i + 3),
            }
        }
        let r0 = DVector::from_iterator(3 * m, model.r0.iter().flat_map(|r| r.iter().copied()));
        let sdu = s * &du;
        let mut x = DVector::zeros(3 * m);
        if !f.is_empty() {
            let sff = DMatrix::from_fn(f.len(), f.len(), |a, b| s[(f[a], f[b])]);
            let rhs = DVector::from_fn(f.len(), |a, _| -(r0[f[a]] + sdu[f[a]]));
            let xf = sff.try_inverse().unwrap() * rhs;
            for (a, &p) in f.iter().enumerate() {
                x[p] = xf[a];
            }
        }
        let r = &r0 + &sdu + s * &x;
        let mut out = InstrumentForce::default();
        for i in 0..m {
            if model.owner[i] != instrument || fresh(model.nodes[i]).is_none() {
                continue;
            }
            let ri = Vector3::new(r[3 * i], r[3 * i + 1], r[3 * i + 2]);
            let p = model.rest[i].coords + fresh(model.nodes[i]).unwrap();
            out.force -= ri;
            out.torque += (p - handle).cross(&(-ri));
        }
        out
    }

    /// Three instruments and unowned nodes over a random SPD stiffness: each
    /// instrument's force equals the reference over the whole set, as the
    /// released set changes from sample to sample (the cached factor is
    /// never reused for another set or another instrument).
    #[test]
    fn blocks_give_the_whole_set_answer() {
        let m = 14;
        let mut x = 7u64;
        let mut next = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let a = DMatrix::from_fn(3 * m, 3 * m, |_, _| next());
        // SPD, N/m, and a little asymmetric by rounding as `C^-1` is.
        let s = (&a * a.transpose() + DMatrix::identity(3 * m, 3 * m) * 3.0 * m as f64) * 100.0;
        let owner: Vec<u16> = (0..m).map(|i| [0, 1, 2, u16::MAX][i % 4]).collect();
        let u0: Vec<Vector3<f64>> = (0..m)
            .map(|_| Vector3::new(next(), next(), next()) * 1e-3)
            .collect();
        let r0: Vec<Vector3<f64>> = (0..m)
            .map(|_| Vector3::new(next(), next(), next()))
            .collect();
        let nodes: Vec<u32> = (0..m as u32).map(|i| 100 + 3 * i).collect();
        let mut model = ForceModel::new(nodes.clone(), owner, u0.clone(), r0, &s);
        model.rest = (0..m)
            .map(|_| nalgebra::Point3::new(next(), next(), next()) * 0.01)
            .collect();
        model.frame = 3;
        let handle = Vector3::new(0.01, 0.02, -0.01);
        let mut ws = ForceWorkspace::default();
        let mut checked_release = 0;
        for instrument in [0u16, 1, 2, 7] {
            for sample in 0..40u32 {
                let shift = Vector3::new(next(), next(), next()) * 1e-4;
                // Release a pattern of nodes that changes with the sample
                // (sets of equal size in turn: the cache must compare sets).
                let fresh = |n: u32| {
                    let i = ((n - 100) / 3) as usize;
                    ((n / 3 + sample) % 3 != 0).then(|| u0[i] + shift)
                };
                let got = model.instrument_force(instrument, fresh, &handle, &mut ws);
                let want = reference(&model, &s, instrument, &fresh, &handle);
                let scale = want.force.norm().max(1.0);
                assert!(
                    (got.force - want.force).norm() < 1e-9 * scale,
                    "sample {sample}, instrument {instrument}: {got:?} vs {want:?}"
                );
                assert!((got.torque - want.torque).norm() < 1e-9 * scale);
                if instrument == 7 {
                    assert_eq!(got, InstrumentForce::default());
                } else if nodes.iter().any(|&n| fresh(n).is_none()) {
                    checked_release += 1;
                }
            }
        }
        assert!(checked_release > 100);
    }
}
