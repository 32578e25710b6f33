//! The injury measures a frame carries ([`fissure_engine::sim::core::injury`]),
//! through the whole step:
//!
//! * a plate larger than a block's top, bottom fixed, `nu = 0`, pressed by
//!   `d`: uniaxial strain, exact for linear tetrahedra, so the contact
//!   pressure is `E d / L` at every vertex of the top (mean and peak), the
//!   contact area is the top's, and the largest principal Green-Lagrange
//!   strain is the uniaxial one, `((1 - d/L)^2 - 1) / 2` along the press and
//!   0 across it: the largest is 0; pressing twice as deep doubles the
//!   pressure, retracting clears it, and the pressure-time product sums
//!   the frames' held pressures;
//! * a strain picture comes only when the session's worst strain grows by
//!   a quarter.
//!
//! The strain of a stretched and turned tetrahedron against the analytic
//! Green-Lagrange strain, and the closed-form eigenvalue against an
//! iterative solver, are the module's unit tests.

use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::scene::Scene;
use fissure_engine::sim::core::engine::Model;
use fissure_engine::sim::core::snapshot::Snapshot;
use fissure_engine::sim::core::stepped::SteppedRunner;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::sync::Arc;

/// Face A down, tip towards +y (cube.toml).
fn flat(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::new_normalize(Quaternion::new(0.5, -0.5, 0.5, 0.5)),
    )
}

/// Handle height at which face A touches the cube's top (z = 40 mm), m.
const TOUCH_Z: f64 = 0.04 + 0.00075;

/// The cube with `nu = 0` and a left plate larger than its top.
fn wide_plate_cube() -> Scene {
    let mut text = include_str!("../../scenes/cube.toml").to_owned();
    for (from, to) in [
        ("poisson_ratio = 0.45", "poisson_ratio = 0.0"),
        ("width_m = 0.010", "width_m = 0.060"),
        ("length_m = 0.030", "length_m = 0.060"),
        ("nodes_per_face = 150", "nodes_per_face = 600"),
    ] {
        assert!(text.contains(from), "cube.toml has no {from:?}");
        text = text.replacen(from, to, 1);
    }
    Scene::parse(&text, "cube (wide plate)").expect("the variant parses")
}

/// Smooth 0 -> 1 (cosine ramp) on `[a, b]`.
fn ramp(t: f64, a: f64, b: f64) -> f64 {
    let s = ((t - a) / (b - a)).clamp(0.0, 1.0);
    0.5 - 0.5 * (std::f64::consts::PI * s).cos()
}

/// A stepped session of the left plate at `(x, y)` whose face A is
/// `depth(t)` below the cube's top (m), sampled every 2 ms to `end_s`, the
/// right plate away: every step's snapshot.
fn session(
    scene: &Scene,
    x: f64,
    y: f64,
    depth: impl Fn(f64) -> f64,
    end_s: f64,
) -> Vec<Arc<Snapshot>> {
    let model = Arc::new(Model::build(scene).expect("the model builds"));
    let mut runner =
        SteppedRunner::for_scene(scene, model, ColumnPolicy::Compute).expect("the runner starts");
    let away = flat(0.029, 0.005, 0.08);
    let mut steps = Vec::new();
    let mut answers = Vec::new();
    for k in 0..=((end_s / 0.002).round() as usize) {
        let t = k as f64 * 0.002;
        let poses = [(0, flat(x, y, TOUCH_Z - depth(t))), (1, away)];
        answers.clear();
        runner.tick(
            t,
            &poses,
            &mut |d| steps.push(d.snapshot.clone()),
            &mut answers,
        );
    }
    steps
}

/// The step snapshot at `t` (s).
fn at(steps: &[Arc<Snapshot>], t: f64) -> &Snapshot {
    steps
        .iter()
        .find(|s| (s.sim_time_s - t).abs() < 1e-9)
        .unwrap_or_else(|| panic!("no step at t = {t} s"))
}

/// A uniform press by `d`: `E d / L` under the plate at every vertex (mean
/// and peak), the top's area in contact, no positive principal strain; at
/// `2 d` twice the pressure; retracted, none. The session sums are the
/// frames' held pressures.
#[test]
fn a_uniform_press_has_the_analytic_contact_pressure_and_strain() {
    let scene = wide_plate_cube();
    let d = 0.001;
    let depth = |t: f64| {
        -0.0005 + (d + 0.0005) * ramp(t, 0.0, 0.05) + d * ramp(t, 0.1, 0.15)
            - (2.0 * d + 0.0005) * ramp(t, 0.2, 0.25)
    };
    let steps = session(&scene, 0.02, -0.01, depth, 0.3);
    let (e, l) = (3000.0, 0.04);
    for (t, d) in [(0.1, d), (0.2, 2.0 * d), (0.28, 0.0)] {
        let f = &at(&steps, t).frame_summary;
        let p = f.instruments[0].pressure;
        assert_eq!(f.instruments[1].pressure.contact_area_m2, 0.0);
        if d == 0.0 {
            assert_eq!(p.contact_area_m2, 0.0, "retracted: {p:?}");
            assert_eq!(p.mean_pa, 0.0);
            assert!(f.strain.max_principal.abs() < 1e-12, "{:?}", f.strain);
            continue;
        }
        let want = e * d / l;
        assert!(
            (p.mean_pa - want).abs() <= 1e-6 * want,
            "d = {d}: mean {} Pa, E d / L = {want} Pa",
            p.mean_pa
        );
        assert!(
            (p.peak_pa - want).abs() <= 1e-6 * want,
            "d = {d}: peak {} Pa, E d / L = {want} Pa",
            p.peak_pa
        );
        assert!(
            (p.contact_area_m2 - l * l).abs() <= 1e-12,
            "area {} m^2, the top's {} m^2",
            p.contact_area_m2,
            l * l
        );
        // Pressed along z: E_zz = ((1 - d/L)^2 - 1) / 2 < 0, and 0 across.
        assert!(
            f.strain.max_principal.abs() <= 1e-9,
            "largest principal strain {} (0 across the press)",
            f.strain.max_principal
        );
        assert_eq!(f.strain.volume_above_m3, 0.0);
    }
    // The sums: each frame's mean pressure held until the next frame.
    let mut product = 0.0;
    for w in steps.windows(2) {
        product += w[0].frame_summary.instruments[0].pressure.mean_pa
            * (w[1].sim_time_s - w[0].sim_time_s);
    }
    let last = steps.last().unwrap().frame_summary.instruments[0].pressure;
    assert!(
        (last.pressure_time_pa_s - product).abs() <= 1e-12 * product,
        "{} Pa s against {product} Pa s",
        last.pressure_time_pa_s
    );
    // 150 Pa at most: below the warning pressure (20 mmHg) throughout.
    assert_eq!(last.time_above_s, 0.0);
}

/// A picture comes with the first frame whose strain passes the floor,
/// and again only when the session's largest strain grows by a quarter: none
/// while a press is held, none for 5% deeper, some for twice as deep,
/// none on retraction.
#[test]
fn a_strain_picture_comes_when_the_worst_strain_grows() {
    let scene = Scene::parse(include_str!("../../scenes/cube.toml"), "cube").expect("parses");
    let n_surface = Model::build(&scene).expect("builds").rest_surface.len();
    let depth = |t: f64| {
        -0.0005
            + 0.0025 * ramp(t, 0.0, 0.1)
            + 0.0001 * ramp(t, 0.2, 0.22)
            + 0.0019 * ramp(t, 0.3, 0.32)
            - 0.0045 * ramp(t, 0.4, 0.42)
    };
    let steps = session(&scene, 0.02, 0.005, depth, 0.5);
    let mut last = 0.0;
    let mut when = Vec::new();
    for s in &steps {
        let f = &s.frame_summary;
        let Some(p) = &f.strain_picture else {
            continue;
        };
        assert_eq!(p.strain.len(), n_surface);
        assert_eq!(p.positions.len(), n_surface);
        // The picture shows the tetrahedra at the surface: its largest is
        // the frame's largest at most (the plate presses the surface, so
        // here it is that).
        let top = p.strain.iter().copied().fold(f32::MIN, f32::max) as f64;
        assert!(
            top <= f.strain.max_principal + 1e-6 && top >= 0.5 * f.strain.max_principal,
            "the picture's largest {top}, the frame's {}",
            f.strain.max_principal
        );
        assert!(f.strain.max_principal >= 1.25 * last);
        last = f.strain.max_principal;
        when.push(f.sim_time_s);
    }
    let count = |a: f64, b: f64| when.iter().filter(|&&t| t > a && t <= b).count();
    assert!(count(0.0, 0.1) >= 1, "pictures at {when:?}");
    assert_eq!(count(0.12, 0.3), 0, "pictures at {when:?}");
    assert!(count(0.3, 0.34) >= 1, "pictures at {when:?}");
    assert_eq!(count(0.4, 0.5), 0, "pictures at {when:?}");
}
