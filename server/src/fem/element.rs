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

    /// Displacement gradient `H = Du Dm^-1` (dimensionless), with
    /// `Du = [u1 - u0, u2 - u0, u3 - u0]` from the corner displacements `u`
    /// (m); the deformation gradient is `F = I + H`.
    ///
    /// Formed from displacement differences rather than from positions: a
    /// brain-sized model has coordinates of about 0.1 m, so `X + u` would
    /// round away everything of `u` below about 1e-17 m and leave `F - I`
    /// with an absolute error of about 1e-14 (1e-17 m over a 3 mm edge)
    /// however small the load. `H` keeps full relative precision at any
    /// displacement scale, and `H = 0` exactly at rest.
    pub fn displacement_gradient(&self, u: &[Vector3<f64>; 4]) -> Matrix3<f64> {
        let du = Matrix3::from_columns(&[u[1] - u[0], u[2] - u[0], u[3] - u[0]]);
        du * self.dm_inv
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

/// Cofactor matrix of `x` (`cof(X) = det(X) X^-T`), and `det X`.
#[inline]
pub(super) fn cofactor_det(x: &Matrix3<f64>) -> (Matrix3<f64>, f64) {
    let (c0, c1, c2) = (x.column(0), x.column(1), x.column(2));
    let cof = Matrix3::from_columns(&[c1.cross(&c2), c2.cross(&c0), c0.cross(&c1)]);
    let det = c0.dot(&cof.column(0));
    (cof, det)
}

/// Rotation of the polar decomposition of `F` with `det F > 0` by Higham's
/// iteration `X <- (X + X^-T) / 2`, `X^-T = cof(X) / det X` (a handful of
/// 3 x 3 cofactor matrices for near-rotations, much cheaper than an SVD).
/// `None` when `det F <= 0` or the iteration fails.
///
/// Stopping rule: the iteration maps each singular value `1 + e` to
/// `1 + e^2 / 2 + O(e^3)`, so the change of an iteration measures the error
/// of its input and the output's error is about half its square. The
/// iteration stops after a change below 1e-8 (entry-wise): the result is
/// then orthogonal to about 1e-16, the rounding of its entries
/// (`|R^T R - I| < 1e-15`, tested), one inversion earlier than waiting for
/// the change itself to reach rounding.
pub fn polar_rotation_fast(f: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let (_, det) = cofactor_det(f);
    if !(det > 0.0) {
        return None;
    }
    let mut x = *f;
    for _ in 0..60 {
        let (cof, det) = cofactor_det(&x);
        if !(det > 0.0 && det.is_finite()) {
            return None;
        }
        let next = 0.5 * (x + cof * det.recip());
        let change = (next - x).abs().max();
        x = next;
        if change < 1e-8 {
            return Some(x);
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// `det(I + H) - 1` without cancellation: the characteristic expansion
/// `tr H + I2(H) + det H`, `I2 = ((tr H)^2 - tr(H^2)) / 2`, keeps full
/// relative precision for small `H`, where `det(I + H) - 1` would lose it.
pub fn det_minus_one(h: &Matrix3<f64>) -> f64 {
    let tr = h.trace();
    let tr_h2 = (h * h).trace();
    tr + 0.5 * (tr * tr - tr_h2) + h.determinant()
}

/// `x - ln(1 + x)` for `x > -1`, to full relative precision near 0 (where it
/// is `x^2 / 2 - x^3 / 3 + ...` and the direct difference would cancel):
/// the Taylor series up to `x^14` for `|x| < 0.05` (truncation below 3e-17
/// relative), the direct difference beyond (relative error below 1e-14).
pub fn x_minus_ln1p(x: f64) -> f64 {
    if x.abs() < 0.05 {
        // sum_{k=2}^{14} (-1)^k x^k / k by Horner's rule.
        let mut acc = 0.0;
        for k in (2..=14).rev() {
            let c = if k % 2 == 0 { 1.0 } else { -1.0 } / k as f64;
            acc = acc * x + c;
        }
        acc * x * x
    } else {
        x - x.ln_1p()
    }
}

/// A strain-energy density and the scale of its rounding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyDensity {
    /// The density, J/m^3 (>= 0 for the neo-Hookean model).
    pub value: f64,
    /// Sum of the magnitudes of the terms it is computed from, J/m^3: the
    /// value's rounding error is a few `f64::EPSILON` times this.
    pub magnitude: f64,
}

/// Compressible neo-Hookean strain-energy density from the displacement
/// gradient `H` (`F = I + H`), free of cancellation for small `H`:
/// with `J - 1 = det_minus_one(H)` and `ln J = ln_1p(J - 1)`,
/// `psi = mu/2 (|F|^2 - 3 - 2 ln J) + lambda/2 (ln J)^2` where
/// `|F|^2 - 3 - 2 ln J = |H|^2 - 2 I2(H) - 2 det H + 2 (x - ln(1 + x))`,
/// `x = J - 1` (the `2 tr H` terms cancel exactly). `None` when `J <= 0`.
pub fn neo_hookean_energy(h: &Matrix3<f64>, lambda: f64, mu: f64) -> Option<EnergyDensity> {
    let jm1 = det_minus_one(h);
    if !(jm1 > -1.0) {
        return None;
    }
    let tr = h.trace();
    let i2 = 0.5 * (tr * tr - (h * h).trace());
    let det = h.determinant();
    let hh = h.norm_squared();
    let phi = x_minus_ln1p(jm1);
    let lj = jm1.ln_1p();
    let iso = hh - 2.0 * i2 - 2.0 * det + 2.0 * phi;
    Some(EnergyDensity {
        value: 0.5 * mu * iso + 0.5 * lambda * lj * lj,
        // |lambda|: the deviatoric part of the nodal-pressure element takes
        // a negative one (`-2 mu / 3`).
        magnitude: 0.5 * mu * (hh + 2.0 * i2.abs() + 2.0 * det.abs() + 2.0 * phi)
            + 0.5 * lambda.abs() * lj * lj,
    })
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

/// Neo-Hookean element internal forces (N, `f_a = V P g_a`) from the
/// displacement gradient `H` (`F = I + H`, `ln J` from [`det_minus_one`]).
/// `None` when `J <= 0`.
pub fn neo_hookean_forces(
    geom: &TetGeometry,
    h: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
) -> Option<[Vector3<f64>; 4]> {
    let (p, _) = neo_hookean_stress_h(h, lambda, mu)?;
    let v = geom.volume;
    Some(geom.grads.map(|g| v * (p * g)))
}

/// First Piola-Kirchhoff stress (Pa) and `F^-1` from the displacement
/// gradient, to full relative precision at small `H`: with
/// `G = F^-1 - I = -F^-1 H`, `F - F^-T = H - G^T` and
/// `P = mu (H - G^T) + lambda ln J (I + G^T)` (the direct `F - F^-T` would
/// carry an absolute error of eps). `None` when `J <= 0`.
fn neo_hookean_stress_h(
    h: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    let jm1 = det_minus_one(h);
    if !(jm1 > -1.0) {
        return None;
    }
    let f_inv = (Matrix3::identity() + h).try_inverse()?;
    let g_t = -(f_inv * h).transpose();
    let p = mu * (h - g_t) + lambda * jm1.ln_1p() * (Matrix3::identity() + g_t);
    Some((p, f_inv))
}

/// [`neo_hookean_element`] from the displacement gradient `H` (`F = I + H`,
/// `ln J` from [`det_minus_one`], see [`TetGeometry::displacement_gradient`]).
pub fn neo_hookean_element_h(
    geom: &TetGeometry,
    h: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
) -> Option<([Vector3<f64>; 4], ElementMatrix)> {
    let (p, f_inv) = neo_hookean_stress_h(h, lambda, mu)?;
    let lj = det_minus_one(h).ln_1p();
    Some(element_from_stress(geom, &p, &f_inv, lj, lambda, mu))
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
    let lj = j.ln();
    let p = mu * (f - f_inv.transpose()) + lambda * lj * f_inv.transpose();
    Some(element_from_stress(geom, &p, &f_inv, lj, lambda, mu))
}

/// Element forces and tangent from the stress `P`, `F^-1` and `ln J`.
fn element_from_stress(
    geom: &TetGeometry,
    p: &Matrix3<f64>,
    f_inv: &Matrix3<f64>,
    lj: f64,
    lambda: f64,
    mu: f64,
) -> ([Vector3<f64>; 4], ElementMatrix) {
    let f_inv = *f_inv;
    let f_inv_t = f_inv.transpose();
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
    (forces, k)
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

    fn sample_h(scale: f64) -> Matrix3<f64> {
        scale * Matrix3::new(0.3, -0.2, 0.5, 0.1, -0.4, 0.25, -0.35, 0.15, 0.2)
    }

    #[test]
    fn displacement_gradient_matches_positions() {
        let g = sample_tet();
        let x0 = [
            Vector3::new(0.001, -0.002, 0.0005),
            Vector3::new(0.011, 0.001, -0.001),
            Vector3::new(0.002, 0.009, 0.002),
            Vector3::new(0.003, 0.002, 0.012),
        ];
        let u = [
            Vector3::new(1e-4, 2e-4, -1e-4),
            Vector3::new(-3e-4, 1e-4, 0.0),
            Vector3::new(2e-4, -2e-4, 1e-4),
            Vector3::new(0.0, 1e-4, 3e-4),
        ];
        let x = [x0[0] + u[0], x0[1] + u[1], x0[2] + u[2], x0[3] + u[3]];
        let f = g.deformation_gradient(&x);
        let h = g.displacement_gradient(&u);
        assert!((f - Matrix3::identity() - h).abs().max() < 1e-13);
        assert_eq!(
            g.displacement_gradient(&[Vector3::zeros(); 4]),
            Matrix3::zeros()
        );
    }

    #[test]
    fn det_minus_one_and_x_minus_ln1p_are_accurate() {
        for scale in [0.3, 1e-3, 1e-9] {
            let h = sample_h(scale);
            let direct = (Matrix3::identity() + h).determinant() - 1.0;
            let got = det_minus_one(&h);
            // The direct difference carries an absolute error of about eps.
            assert!((got - direct).abs() < 4.0 * f64::EPSILON, "{scale}");
            // First order: tr H.
            if scale < 1e-6 {
                assert!((got - h.trace()).abs() < 10.0 * scale * scale);
            }
        }
        // Series and direct branch agree at the switch and follow x^2 / 2.
        for x in [0.049_999_999, 0.050_000_001, -0.049_999_999, -0.050_000_001] {
            let direct = x - f64::ln_1p(x);
            assert!((x_minus_ln1p(x) - direct).abs() < 1e-14 * direct, "{x}");
        }
        for x in [1e-3f64, -1e-5, 1e-9, 1e-200] {
            let want = (2..=7)
                .map(|k| if k % 2 == 0 { 1.0 } else { -1.0 } * x.powi(k) / k as f64)
                .sum::<f64>();
            assert!((x_minus_ln1p(x) - want).abs() <= 1e-15 * want, "{x}");
        }
        assert_eq!(x_minus_ln1p(0.0), 0.0);
    }

    #[test]
    fn neo_hookean_energy_keeps_precision_at_light_load() {
        let g = sample_tet();
        let (lambda, mu) = (2.5e4, 1.0e3);
        // Moderate strain: equal to the F-based density.
        let h = sample_h(0.2);
        let f = Matrix3::identity() + h;
        let want = neo_hookean_density(&f, lambda, mu).unwrap();
        let got = neo_hookean_energy(&h, lambda, mu).unwrap();
        assert!((got.value - want).abs() < 1e-12 * want);
        assert!(got.magnitude >= got.value);
        // Tiny strain: the density is the linear one, `mu eps:eps +
        // lambda/2 tr(eps)^2`, to relative O(|H|); the F-based form would
        // be rounding noise there (|H|^2 = 1e-20 below eps).
        for scale in [1e-4, 1e-10] {
            let u = [
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(3.0, -1.0, 2.0) * scale * 0.01,
                Vector3::new(-1.0, 2.0, 1.0) * scale * 0.01,
                Vector3::new(2.0, 1.0, -2.0) * scale * 0.01,
            ];
            let h = g.displacement_gradient(&u);
            let lin = linear_energy(&g, lambda, mu, &u) / g.volume;
            let nh = neo_hookean_energy(&h, lambda, mu).unwrap();
            assert!(
                (nh.value - lin).abs() < 10.0 * scale.max(1e-14) * lin,
                "{scale}: {} vs {lin}",
                nh.value
            );
            // Forces: the linear element force K u to the same order.
            let fl = g.stiffness(lambda, mu)
                * nalgebra::SVector::<f64, 12>::from_iterator(
                    u.iter().flat_map(|v| v.iter().copied()),
                );
            let fn_ = neo_hookean_forces(&g, &h, lambda, mu).unwrap();
            for a in 0..4 {
                let d = fn_[a] - fl.fixed_rows::<3>(3 * a);
                assert!(d.norm() < 10.0 * scale.max(1e-14) * fl.norm(), "{scale}");
            }
        }
        assert_eq!(
            neo_hookean_energy(&Matrix3::zeros(), lambda, mu)
                .unwrap()
                .value,
            0.0
        );
        // Inverted: None.
        let flip = Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.5);
        assert!(neo_hookean_energy(&flip, lambda, mu).is_none());
        assert!(neo_hookean_forces(&g, &flip, lambda, mu).is_none());
        // The H-based element equals the F-based one.
        let (fa, ka) = neo_hookean_element_h(&g, &h, lambda, mu).unwrap();
        let (fb, kb) = neo_hookean_element(&g, &f, lambda, mu).unwrap();
        let fc = neo_hookean_forces(&g, &h, lambda, mu).unwrap();
        for a in 0..4 {
            assert!((fa[a] - fb[a]).norm() < 1e-12 * fb[a].norm().max(1e-12));
            assert!((fa[a] - fc[a]).norm() < 1e-12 * fb[a].norm().max(1e-12));
        }
        assert!((ka - kb).abs().max() < 1e-10 * kb.abs().max());
    }

    #[test]
    fn polar_rotation_fast_is_orthogonal_over_strain_scales() {
        let r = nalgebra::Rotation3::from_euler_angles(-0.4, 0.9, 0.2).into_inner();
        for scale in [0.0, 1e-12, 1e-6, 1e-3, 0.05, 0.3] {
            let s = Matrix3::identity() + sample_h(scale).symmetric_part();
            let got = polar_rotation_fast(&(r * s)).unwrap();
            assert!(
                (got.transpose() * got - Matrix3::identity()).abs().max() < 1e-15,
                "{scale}"
            );
            assert!((got - r).abs().max() < 1e-14, "{scale}");
        }
        assert_eq!(
            polar_rotation_fast(&Matrix3::identity()),
            Some(Matrix3::identity())
        );
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
