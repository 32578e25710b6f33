//! Net force and torque of a set of nodal forces.
//!
//! With reactions `r_i` (N, the force a constraint applies to the tissue at
//! node `i`, position `x_i`), the force the tissue applies to the instrument
//! is `F = -sum_i r_i` and its torque about a point `p` is
//! `T = -sum_i (x_i - p) x r_i` (N m).

use nalgebra::{Point3, Vector3};

/// Net force `sum_i f_i` (N) and torque `sum_i (x_i - p) x f_i` (N m) about
/// `p` of forces `f_i` applied at positions `x_i`.
pub fn net_force_torque(
    positions: impl IntoIterator<Item = Point3<f64>>,
    forces: impl IntoIterator<Item = Vector3<f64>>,
    about: &Point3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let mut f = Vector3::zeros();
    let mut t = Vector3::zeros();
    for (x, r) in positions.into_iter().zip(forces) {
        f += r;
        t += (x - about).cross(&r);
    }
    (f, t)
}

/// Force and torque (about `about`) that the tissue applies to an instrument
/// whose contact nodes carry `reactions`: minus the net of the reactions.
/// `positions` are where the forces act (the nodes' current positions, m).
pub fn instrument_load(
    positions: impl IntoIterator<Item = Point3<f64>>,
    reactions: impl IntoIterator<Item = Vector3<f64>>,
    about: &Point3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let (f, t) = net_force_torque(positions, reactions, about);
    (-f, -t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torque_of_a_couple() {
        let x = [Point3::new(1.0, 0.0, 0.0), Point3::new(-1.0, 0.0, 0.0)];
        let f = [Vector3::new(0.0, 1.0, 0.0), Vector3::new(0.0, -1.0, 0.0)];
        let (nf, nt) = net_force_torque(x, f, &Point3::origin());
        assert!(nf.norm() < 1e-15);
        assert!((nt - Vector3::new(0.0, 0.0, 2.0)).norm() < 1e-15);
        let (inf, _) = instrument_load(
            x[..1].iter().copied(),
            f[..1].iter().copied(),
            &Point3::origin(),
        );
        assert_eq!(inf, Vector3::new(0.0, -1.0, 0.0));
    }
}
