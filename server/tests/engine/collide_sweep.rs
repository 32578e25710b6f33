//! A blade's swept edge against tie segments ([`fissure_engine::collide::tool::sweep`]):
//! for translations of any length the test finds exactly the segments a
//! brute-force solve finds (the parallelogram `a + s e + t d` meets the
//! segment `p + r f` when the 3 x 3 system `s e + t d - r f = p - a` has a
//! solution in `[0, 1]^3`), over random placements and travels up to 10 m
//! per sample; segments through the sweep's edges and vertices count.

use fissure_engine::collide::tool::sweep::edge_sweeps_across;
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
}

fn point(rng: &mut ChaCha8Rng, r: f64) -> Point3<f64> {
    Point3::new(
        uniform(rng, -r, r),
        uniform(rng, -r, r),
        uniform(rng, -r, r),
    )
}

/// The brute-force answer, or `None` when the placement is within `1e-9`
/// of a boundary (either answer is right there).
fn brute(
    a: Point3<f64>,
    e: Vector3<f64>,
    d: Vector3<f64>,
    p: Point3<f64>,
    f: Vector3<f64>,
) -> Option<bool> {
    let m = Matrix3::from_columns(&[e, d, -f]);
    let x = m.try_inverse()? * (p - a);
    let margin = x
        .iter()
        .map(|v| v.min(1.0 - v).abs())
        .fold(f64::INFINITY, f64::min);
    if margin < 1e-9 {
        return None;
    }
    Some(x.iter().all(|v| (0.0..=1.0).contains(v)))
}

#[test]
fn the_swept_edge_cuts_exactly_the_segments_a_brute_force_solve_finds() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let edge = [
        Point3::new(0.0, -0.004, 0.03),
        Point3::new(0.0, 0.004, 0.03),
    ];
    let (mut cut, mut checked) = (0, 0);
    for case in 0..20_000 {
        // Travel from 1 um to 10 m in one sample.
        let travel = 10f64.powf(uniform(&mut rng, -6.0, 1.0));
        let dir = point(&mut rng, 1.0).coords.normalize();
        let start = point(&mut rng, 0.01).coords;
        let p0 = Isometry3::translation(start.x, start.y, start.z);
        let end = start + dir * travel;
        let p1 = Isometry3::translation(end.x, end.y, end.z);
        // Segments near the sweep: a point of the swept parallelogram (or
        // near it) and a random direction and length.
        let (s, t) = (uniform(&mut rng, -0.2, 1.2), uniform(&mut rng, -0.2, 1.2));
        let a = p0 * edge[0];
        let e = edge[1] - edge[0];
        let d = end - start;
        let on = a + e * s + d * t;
        let f = point(&mut rng, 1.0).coords.normalize() * uniform(&mut rng, 1e-4, 0.01);
        let p = on - f * uniform(&mut rng, -0.2, 1.2);
        let q = p + f;
        let Some(want) = brute(a, e, d, p, f) else {
            continue;
        };
        checked += 1;
        let got = edge_sweeps_across(&edge, &p0, &p1, &p, &q);
        assert_eq!(
            got, want,
            "case {case}: travel {travel} m, segment {p} -> {q}"
        );
        cut += want as usize;
    }
    assert!(
        checked > 19_000 && cut > 3000,
        "{checked} checked, {cut} cut"
    );
}

#[test]
fn segments_through_the_sweeps_corners_and_edges_are_cut() {
    let edge = [
        Point3::new(0.0, -0.004, 0.03),
        Point3::new(0.0, 0.004, 0.03),
    ];
    let p0 = Isometry3::translation(0.0, 0.0, 0.0);
    let p1 = Isometry3::translation(0.0, 0.0, 0.01);
    // The swept rectangle: x = 0, y in [-4, 4] mm, z in [30, 40] mm.
    for (y, z) in [
        (-0.004, 0.03),
        (0.004, 0.04),
        (0.0, 0.03),
        (0.004, 0.035),
        (0.0, 0.035),
    ] {
        let p = Point3::new(-0.001, y, z);
        let q = Point3::new(0.001, y, z);
        assert!(
            edge_sweeps_across(&edge, &p0, &p1, &p, &q),
            "through ({y}, {z})"
        );
        // Ending exactly on the sweep counts too.
        assert!(edge_sweeps_across(
            &edge,
            &p0,
            &p1,
            &p,
            &Point3::new(0.0, y, z)
        ));
    }
    let p = Point3::new(-0.001, 0.0041, 0.035);
    let q = Point3::new(0.001, 0.0041, 0.035);
    assert!(!edge_sweeps_across(&edge, &p0, &p1, &p, &q));
}
