//! The linear tetrahedron (P1): shape-function gradients, the linear-elastic
//! element stiffness, the corotational rotation and the compressible
//! neo-Hookean element force and tangent.
//!
//! Local DOF order of an element is `(node0.x, node0.y, node0.z, node1.x, ...)`.
//! With shape-function gradients `g_a` (1/m) and volume `V` (m^3), the linear
//! element stiffness is
//! `K[3a+i, 3b+j] = V (lambda g_a,i g_b,j + mu g_a,j g_b,i + mu delta_ij g_a . g_b)`,
//! the Hessian of the strain energy `W = V (mu eps:eps + lambda/2 tr(eps)^2)`
//! with `eps = sym(sum_a u_a (x) g_a)`.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use nalgebra::{Matrix3, Point3, SMatrix, Vector3};

/// A 12 x 12 element matrix (N/m).
pub type ElementMatrix = SMatrix<f64, 12, 12>;

/// Rest geometry of one tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetGeometry {
    /// Gradients of the four barycentric shape functions, 1/m.
    pub grads: [Vector3<f64>; 4],
    /// Inverse of the rest edge matrix `Dm = [x1-x0, x2-x0, x3-x0]`, 1/m.
    pub dm_inv: Matrix3<f64>,
    /// Volume, m^3 (> 0).
    pub volume: f64,
}

impl TetGeometry {
    /// Geometry of the tetrahedron with corners `p`; `None` when its signed
    /// volume is not positive or the edge matrix is not invertible.
    pub fn new(p: [Point3<f64>; 4]) -> Option<Self> {
        let dm = Matrix3::from_columns(&[p[1] - p[0], p[2] - p[0], p[3] - p[0]]);
        let volume = dm.determinant() / 6.0;
        if !(volume > 0.0) {
            return None;
        }
        let dm_inv = dm.try_inverse()?;
        // grad N_k (k = 1..3) is row k-1 of Dm^-1; grad N_0 = -sum.
        let g1 = dm_inv.row(0).transpose();
        let g2 = dm_inv.row(1).transpose();
        let g3 = dm_inv.row(2).transpose();
        let grads = [-(g1 + g2 + g3), g1, g2, g3];
        if !grads.iter().all(|g| g.iter().all(|c| c.is_finite())) {
            return None;
        }
        Some(Self {
            grads,
            dm_inv,
            volume,
        })
    }

    /// Deformation gradient `F = Ds Dm^-1` for current corner positions `x`.
    pub fn deformation_gradient(&self, x: &[Vector3<f64>; 4]) -> Matrix3<f64> {
        let ds = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
        ds * self.dm_inv
    }

    /// Linear-elastic element stiffness (N/m) for Lamé parameters (Pa).
    pub fn stiffness(&self, lambda: f64, mu: f64) -> ElementMatrix {
        let mut k = ElementMatrix::zeros();
        let v = self.volume;
        for a in 0..4 {
            for b in 0..4 {
                let (ga, gb) = (&self.grads[a], &self.grads[b]);
                let dot = ga.dot(gb);
                for i in 0..3 {
                    for j in 0..3 {
                        let mut s = lambda * ga[i] * gb[j] + mu * ga[j] * gb[i];
                        if i == j {
                            s += mu * dot;
                        }
                        k[(3 * a + i, 3 * b + j)] = v * s;
                    }
                }
            }
        }
        k
    }
}

/// Strain energy (J) of a linear-elastic tetrahedron under nodal displacements
/// `u` (m): `V (mu eps:eps + lambda/2 tr(eps)^2)`. An independent statement of
/// the model used to check [`TetGeometry::stiffness`].
pub fn linear_energy(geom: &TetGeometry, lambda: f64, mu: f64, u: &[Vector3<f64>; 4]) -> f64 {
    let mut grad_u = Matrix3::zeros();
    for a in 0..4 {
        grad_u += u[a] * geom.grads[a].transpose();
    }
    let eps = 0.5 * (grad_u + grad_u.transpose());
    geom.volume * (mu * eps.component_mul(&eps).sum() + 0.5 * lambda * eps.trace().powi(2))
}

/// Rotation of the polar decomposition `F = R S` (R proper orthogonal), by the
/// SVD with the sign of the smallest singular direction flipped when
/// `det F < 0`. Returns the identity for a non-finite `F`.
pub fn polar_rotation(f: &Matrix3<f64>) -> Matrix3<f64> {
    if !f.iter().all(|c| c.is_finite()) {
        return Matrix3::identity();
    }
    let svd = f.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        // Flip the column of U for the smallest singular value.
        let (imin, _) =
            svd.singular_values
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |acc, (i, &s)| if s < acc.1 { (i, s) } else { acc },
                );
        let mut u2 = u;
        u2.column_mut(imin).neg_mut();
        r = u2 * vt;
    }
    r
}

/// Rotation of the polar decomposition of `F` with `det F > 0` by Higham's
/// iteration `X <- (X + X^-T) / 2` (quadratic convergence; a handful of 3 x 3
/// inversions for near-rotations, much cheaper than an SVD). `None` when
/// `det F <= 0` or the iteration fails.
pub fn polar_rotation_fast(f: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    if !(f.determinant() > 0.0) {
        return None;
    }
    let mut x = *f;
    for _ in 0..60 {
        let next = 0.5 * (x + x.try_inverse()?.transpose());
        let change = (next - x).abs().max();
        x = next;
        if change < 1e-14 {
            return Some(x);
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Compressible neo-Hookean strain-energy density (J/m^3):
/// `psi = mu/2 (tr(F^T F) - 3) - mu ln J + lambda/2 (ln J)^2`, `J = det F`.
/// `None` when `J <= 0`.
pub fn neo_hookean_density(f: &Matrix3<f64>, lambda: f64, mu: f64) -> Option<f64> {
    let j = f.determinant();
    if !(j > 0.0) {
        return None;
    }
    let lj = j.ln();
    Some(0.5 * mu * (f.norm_squared() - 3.0) - mu * lj + 0.5 * lambda * lj * lj)
}

/// First Piola-Kirchhoff stress of the neo-Hookean model (Pa):
/// `P = mu (F - F^-T) + lambda ln J F^-T`. `None` when `J <= 0`.
pub fn neo_hookean_stress(f: &Matrix3<f64>, lambda: f64, mu: f64) -> Option<Matrix3<f64>> {
    let j = f.determinant();
    if !(j > 0.0) {
        return None;
    }
    let f_inv_t = f.try_inverse()?.transpose();
    Some(mu * (f - f_inv_t) + lambda * j.ln() * f_inv_t)
}

/// Neo-Hookean element internal force (N, `f_a = V P g_a`) and tangent
/// stiffness (N/m, `dP = mu dF + (mu - lambda ln J) F^-T dF^T F^-T +
/// lambda tr(F^-1 dF) F^-T`). `None` when `J <= 0`.
pub fn neo_hookean_element(
    geom: &TetGeometry,
    f: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
) -> Option<([Vector3<f64>; 4], ElementMatrix)> {
    let j = f.determinant();
    if !(j > 0.0) {
        return None;
    }
    let f_inv = f.try_inverse()?;
    let f_inv_t = f_inv.transpose();
    let lj = j.ln();
    let p = mu * (f - f_inv_t) + lambda * lj * f_inv_t;
    let v = geom.volume;
    let forces = geom.grads.map(|g| v * (p * g));
    let mut k = ElementMatrix::zeros();
    for b in 0..4 {
        for jx in 0..3 {
            // dF for a unit displacement of node b along axis jx: e_jx (x) g_b.
            let mut df = Matrix3::zeros();
            df.set_row(jx, &geom.grads[b].transpose());
            let dp = mu * df
                + (mu - lambda * lj) * f_inv_t * df.transpose() * f_inv_t
                + lambda * (f_inv * df).trace() * f_inv_t;
            for a in 0..4 {
                let col = v * (dp * geom.grads[a]);
                for i in 0..3 {
                    k[(3 * a + i, 3 * b + jx)] = col[i];
                }
            }
        }
    }
    // Symmetrise round-off.
    let k = 0.5 * (k + k.transpose());
    Some((forces, k))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_tet() -> TetGeometry {
        TetGeometry::new([
            Point3::new(0.001, -0.002, 0.0005),
            Point3::new(0.011, 0.001, -0.001),
            Point3::new(0.002, 0.009, 0.002),
            Point3::new(0.003, 0.002, 0.012),
        ])
        .unwrap()
    }

    #[test]
    fn stiffness_equals_hessian_of_energy() {
        let g = sample_tet();
        let (lambda, mu) = (2.3e4, 1.1e3);
        let k = g.stiffness(lambda, mu);
        // The energy is quadratic: central second differences are exact up to
        // round-off, independent of h.
        let h = 1e-4;
        let energy = |du: &[(usize, f64)]| {
            let mut u = [Vector3::zeros(); 4];
            for &(d, s) in du {
                u[d / 3][d % 3] += s;
            }
            linear_energy(&g, lambda, mu, &u)
        };
        let scale = k.abs().max();
        for p in 0..12 {
            for q in 0..12 {
                let num = (energy(&[(p, h), (q, h)])
                    - energy(&[(p, h), (q, -h)])
                    - energy(&[(p, -h), (q, h)])
                    + energy(&[(p, -h), (q, -h)]))
                    / (4.0 * h * h);
                assert!(
                    (num - k[(p, q)]).abs() < 1e-7 * scale,
                    "K[{p},{q}] = {} vs {num}",
                    k[(p, q)]
                );
            }
        }
    }

    #[test]
    fn stiffness_has_six_rigid_modes() {
        let g = sample_tet();
        let k = g.stiffness(5e3, 1e3);
        let eig = k.symmetric_eigenvalues();
        let max = eig.max();
        let zeros = eig.iter().filter(|&&e| e.abs() < 1e-10 * max).count();
        assert_eq!(zeros, 6);
        assert!(eig.iter().all(|&e| e > -1e-10 * max));
    }

    #[test]
    fn neo_hookean_tangent_matches_linear_at_rest_and_force_is_gradient() {
        let g = sample_tet();
        let (lambda, mu) = (4e3, 1e3);
        let (f0, k0) = neo_hookean_element(&g, &Matrix3::identity(), lambda, mu).unwrap();
        assert!(f0.iter().all(|f| f.norm() < 1e-12));
        let kl = g.stiffness(lambda, mu);
        assert!((k0 - kl).abs().max() < 1e-9 * kl.abs().max());
        // Force = gradient of the energy at a deformed state.
        let x0 = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.01, 0.001, 0.0),
            Vector3::new(0.001, 0.011, 0.0),
            Vector3::new(0.0, 0.001, 0.009),
        ];
        let energy = |x: &[Vector3<f64>; 4]| {
            g.volume * neo_hookean_density(&g.deformation_gradient(x), lambda, mu).unwrap()
        };
        let fdef = g.deformation_gradient(&x0);
        let (forces, _) = neo_hookean_element(&g, &fdef, lambda, mu).unwrap();
        let h = 1e-8;
        for a in 0..4 {
            for i in 0..3 {
                let (mut xp, mut xm) = (x0, x0);
                xp[a][i] += h;
                xm[a][i] -= h;
                let num = (energy(&xp) - energy(&xm)) / (2.0 * h);
                assert!(
                    (num - forces[a][i]).abs() < 1e-5 * forces[a].norm().max(1e-3),
                    "{num} vs {}",
                    forces[a][i]
                );
            }
        }
    }

    #[test]
    fn polar_rotation_is_proper() {
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -0.7, 1.1).into_inner();
        let s = Matrix3::new(1.1, 0.05, 0.0, 0.05, 0.9, 0.02, 0.0, 0.02, 1.0);
        let got = polar_rotation(&(r * s));
        assert!((got - r).abs().max() < 1e-12);
        // A reflected F still gives a proper rotation.
        let fast = polar_rotation_fast(&(r * s)).unwrap();
        assert!((fast - r).abs().max() < 1e-12);
        let refl = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -0.1);
        assert!(polar_rotation_fast(&refl).is_none());
        assert!((polar_rotation(&refl).determinant() - 1.0).abs() < 1e-12);
    }
}
