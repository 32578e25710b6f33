//! The nonlinear strategies' compliance patch (`fem::tangent`): the force
//! loop's local model between their steps is the first-order expansion of
//! the full solve about the last step. Its prediction of the reactions
//! under a new enforced displacement `d + delta` equals the last step's at
//! `delta = 0` and its error shrinks as `delta^2` for `neo-hookean` (the
//! exact tangent), as `delta` or faster for `corotational` (the
//! frozen-rotation tangent its iterations use).

use fissure_engine::fem::corotational::IterativeOptions;
use fissure_engine::fem::foundation::{Foundation, outer_faces_where};
use fissure_engine::fem::{
    CompliancePatch, Element, Material, Prescribed, SolverOptions, Strategy, build_solver,
};
use fissure_engine::mesh::blocks::cube;
use nalgebra::{DMatrix, DVector, Vector3};

const L: f64 = 0.02;

/// The local model's reactions at the pressed nodes for their enforced
/// displacements `u` (m): `free + C f = X + u` on those nodes.
fn predicted(
    patch: &CompliancePatch,
    rest: &[nalgebra::Point3<f64>],
    pressed: &[Prescribed],
) -> Vec<Vector3<f64>> {
    let index: Vec<usize> = pressed
        .iter()
        .map(|p| {
            patch
                .nodes
                .iter()
                .position(|&n| n == p.node)
                .expect("every pressed node is in the patch")
        })
        .collect();
    let m = pressed.len();
    let mut c = DMatrix::zeros(3 * m, 3 * m);
    let mut g = DVector::zeros(3 * m);
    for (a, &i) in index.iter().enumerate() {
        for (b, &j) in index.iter().enumerate() {
            c.view_mut((3 * a, 3 * b), (3, 3))
                .copy_from(&patch.block(i, j));
        }
        let want = rest[pressed[a].node as usize] + pressed[a].displacement;
        g.fixed_rows_mut::<3>(3 * a)
            .copy_from(&(want - patch.free_positions[i]));
    }
    let f = c.cholesky().expect("the patch block is SPD").solve(&g);
    (0..m)
        .map(|a| Vector3::new(f[3 * a], f[3 * a + 1], f[3 * a + 2]))
        .collect()
}

/// What a patch is checked on: the strategy, its options (element,
/// foundation), Poisson's ratio and the step's press `d` (m).
struct Setup {
    strategy: Strategy,
    options: SolverOptions,
    nu: f64,
    d: Vector3<f64>,
}

impl Setup {
    /// A 2.5 mm press with a sideways drag on the stem's cube: 12% strain,
    /// where the tangent differs from the rest stiffness.
    fn plain(strategy: Strategy) -> Self {
        Self {
            strategy,
            options: SolverOptions::default(),
            nu: 0.45,
            d: Vector3::new(1e-3, 0.0, -2.5e-3),
        }
    }

    /// A 10 % press with a drag, a stiff foundation (1e6 Pa/m) on the four
    /// sides, which bulge into it; with `element` at `nu`.
    fn on_foundation(strategy: Strategy, element: Element, nu: f64) -> Self {
        let mesh = cube(L, 4);
        let sides = outer_faces_where(&mesh, |c| {
            c.z > 1e-12 && c.z < L - 1e-12 && c.x.min(c.y).min(L - c.x).min(L - c.y) < 1e-12
        });
        Self {
            strategy,
            options: SolverOptions {
                foundation: Some(Foundation {
                    stiffness_pa_per_m: 1e6,
                    faces: sides,
                }),
                iterative: IterativeOptions::reference(),
                element,
                ..SolverOptions::default()
            },
            nu,
            d: Vector3::new(1e-3, 0.0, -2e-3),
        }
    }
}

/// Largest reaction error of the local model against a full solve at
/// `d + delta`, relative to the largest full reaction, after a step at `d`
/// (bottom fixed, the top's middle pressed).
fn tangent_error(setup: &Setup, delta: f64) -> f64 {
    let strategy = setup.strategy;
    let mesh = cube(L, 4);
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: setup.nu,
    };
    let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z < 1e-12)
        .collect();
    let top: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| {
            let p = mesh.nodes[i as usize];
            (p.z - L).abs() < 1e-12
                && (p.x - L / 2.0).abs() < 0.3 * L
                && (p.y - L / 2.0).abs() < 0.3 * L
        })
        .collect();
    let press = |d: Vector3<f64>| -> Vec<Prescribed> {
        top.iter()
            .map(|&node| Prescribed {
                node,
                displacement: d,
            })
            .collect()
    };
    let d = setup.d;
    let step = Vector3::new(0.3, -0.2, -1.0) * delta;
    let mut s = build_solver(strategy, &mesh, mat, &fixed, &setup.options).unwrap();
    let r0 = s.solve(&press(d)).unwrap().reactions.clone();
    let mut patch = CompliancePatch::default();
    let mut nodes = top.clone();
    nodes.extend(0..8); // some far nodes too (the bottom ones are left out)
    assert!(
        s.compliance_patch(&nodes, &mut patch),
        "{strategy:?} gives a patch"
    );
    assert!(!patch.linear);
    assert!(
        patch.nodes.iter().all(|n| !fixed.contains(n)),
        "fixed nodes have no compliance"
    );
    // At the step's own displacement the patch gives the step's reactions.
    let at_step = predicted(&patch, &mesh.nodes, &press(d));
    let scale = r0.iter().fold(0.0f64, |m, r| m.max(r.norm()));
    for (p, r) in at_step.iter().zip(&r0) {
        assert!(
            (p - r).norm() < 1e-7 * scale,
            "{strategy:?}: at the step {p} vs {r}"
        );
    }
    let moved = press(d + step);
    let guess = predicted(&patch, &mesh.nodes, &moved);
    let full = s.solve(&moved).unwrap().reactions.clone();
    let scale = full.iter().fold(0.0f64, |m, r| m.max(r.norm()));
    guess
        .iter()
        .zip(&full)
        .map(|(g, f)| (g - f).norm())
        .fold(0.0, f64::max)
        / scale
}

#[test]
fn the_neo_hookean_patch_is_the_first_order_expansion_of_the_full_solve() {
    let (e1, e2) = (
        tangent_error(&Setup::plain(Strategy::NeoHookean), 2e-4),
        tangent_error(&Setup::plain(Strategy::NeoHookean), 1e-4),
    );
    eprintln!("neo-hookean: error {e1:.3e} at 0.2 mm, {e2:.3e} at 0.1 mm");
    // Second order: halving the step quarters the error (3.2 to 5 allows
    // the third-order term).
    assert!(e1 / e2 > 3.2 && e1 / e2 < 5.0, "{e1} / {e2}");
    assert!(e1 < 1e-2, "{e1}");
}

#[test]
fn the_corotational_patch_predicts_the_full_solve_to_first_order() {
    let (e1, e2) = (
        tangent_error(&Setup::plain(Strategy::Corotational), 2e-4),
        tangent_error(&Setup::plain(Strategy::Corotational), 1e-4),
    );
    eprintln!("corotational: error {e1:.3e} at 0.2 mm, {e2:.3e} at 0.1 mm");
    assert!(e1 / e2 > 1.8, "{e1} / {e2}");
    assert!(e1 < 2e-2, "{e1}");
}

/// The tangent patch holds the foundation: the neo-Hookean patch is the
/// first-order expansion of the full solve (halving the move quarters its
/// error; without the springs in the tangent the error would only halve),
/// with tet4 and with the nodal-pressure element (whose nodal part the
/// tangent holds too, checked at nu = 0.49 where it dominates); the
/// corotational one (frozen rotations) predicts to first order.
#[test]
fn the_tangent_patch_holds_the_foundation() {
    for (element, nu) in [(Element::Tet4, 0.45), (Element::Tet4NodalPressure, 0.49)] {
        let setup = Setup::on_foundation(Strategy::NeoHookean, element, nu);
        let (e1, e2) = (tangent_error(&setup, 2e-4), tangent_error(&setup, 1e-4));
        eprintln!("neo-hookean {element:?}: error {e1:.3e} at 0.2 mm, {e2:.3e} at 0.1 mm");
        assert!(
            e1 / e2 > 3.2 && e1 / e2 < 5.0,
            "neo-Hookean {element:?}: {e1:e} / {e2:e}"
        );
        assert!(e1 < 1e-2, "{element:?}: {e1}");
    }
    let setup = Setup::on_foundation(Strategy::Corotational, Element::Tet4, 0.45);
    let (e1, e2) = (tangent_error(&setup, 2e-4), tangent_error(&setup, 1e-4));
    eprintln!("corotational: error {e1:.3e} at 0.2 mm, {e2:.3e} at 0.1 mm");
    assert!(e1 / e2 > 1.8, "corotational {e1:e} / {e2:e}");
    assert!(e1 < 2e-2, "{e1}");
}
