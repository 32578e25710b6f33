//! Contact mechanics through the whole pipeline (collision stages, rows,
//! the step's contact solve, the force loop), on the stepped runner the
//! server and the study use. Each test states the law it checks:
//!
//! * frictionless quasi-static contact retraces on unloading what it did
//!   on loading, and lets go exactly where the plate leaves the rest
//!   surface;
//! * a plate larger than a block's top, bottom fixed, `nu = 0`: `E A d / L`;
//! * frictionless means no tangential force on a symmetric indentation;
//! * the tissue never pulls the plate (every multiplier >= 0);
//! * a force sample equals a full solve at that sample's poses, with two
//!   instruments moving in opposite directions;
//! * a plate held still settles (the contact set does not flip from one
//!   step to the next);
//! * a plate sliding down the V block's walls: every sample equals a full
//!   solve, and no vertex is pushed by both large faces of one plate;
//! * only tissue the plate covers carries force;
//! * Coulomb friction: the net force stays in the cone at every sample,
//!   sticking and at the onset of slip, and a sliding plate feels `mu`
//!   times the normal force;
//! * the skull surface keeps every node inside it, only pushes, and only
//!   along the inward normal; an open region lets the tissue through.

use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::scene::Scene;
use fissure_engine::sim::core::engine::{Model, StepEngine};
use fissure_engine::sim::core::stepped::{SteppedRunner, home_pose};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
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

fn cube(replacements: &[(&str, &str)]) -> Scene {
    let mut text = include_str!("../../scenes/cube.toml").to_owned();
    for (from, to) in replacements {
        assert!(text.contains(from), "cube.toml has no {from:?}");
        text = text.replacen(from, to, 1);
    }
    Scene::parse(&text, "cube (test variant)").expect("the variant parses")
}

/// A session's answers: per sample, time and each posed instrument's force
/// (N), and with `reference` the full solve's force at that sample.
#[derive(Debug, Default)]
struct Run {
    t: Vec<f64>,
    force: Vec<Vec<Vector3<f64>>>,
    full: Vec<Vec<Vector3<f64>>>,
    flags: Vec<u32>,
    /// Per deformation step: the force on each instrument and the row keys
    /// with a non-zero multiplier.
    steps: Vec<(Vec<Vector3<f64>>, Vec<u64>)>,
}

/// The first instrument's force sample `k` of `r` is its full solve's to
/// 1e-6 of `peak` (N): a force sample equals a full solve at its poses.
fn assert_sample_is_the_full_solve(r: &Run, k: usize, peak: f64) {
    let (s, f) = (r.force[k][0], r.full[k][0]);
    let e = (s - f).norm() / peak;
    assert!(
        e <= 1e-6,
        "t = {} s: sample {s:?} N, full solve {f:?} N ({e} of the peak)",
        r.t[k]
    );
}

/// Runs `tracks[i]` (instrument `i`'s poses at the shared times `times`)
/// through a stepped runner; with `reference`, also a full solve at every
/// sample (a second engine stepped at each sample's time and poses).
fn run(scene: &Scene, times: &[f64], tracks: &[Vec<Isometry3<f64>>], reference: bool) -> Run {
    let model = Arc::new(Model::build(scene).expect("the model builds"));
    let mut runner = SteppedRunner::for_scene(scene, model.clone(), ColumnPolicy::Compute)
        .expect("the runner starts");
    let mut full = reference.then(|| {
        let mut e = StepEngine::new(scene, model.clone(), ColumnPolicy::Compute, None, None)
            .expect("the reference engine starts");
        let rest = e.rest(0.0);
        (e, rest)
    });
    let n = scene.instruments.len();
    let mut out = Run::default();
    let mut answers = Vec::new();
    for (j, &t) in times.iter().enumerate() {
        let poses: Vec<(usize, Isometry3<f64>)> = tracks
            .iter()
            .enumerate()
            .map(|(i, tr)| (i, tr[j]))
            .collect();
        answers.clear();
        runner.tick(
            t,
            &poses,
            &mut |d| {
                let fm = &d.snapshot.force_model;
                let mut keys: Vec<u64> = fm
                    .step_rows
                    .iter()
                    .zip(&fm.step_lambda)
                    .filter(|(_, l)| **l != 0.0)
                    .map(|(r, _)| r.key)
                    .collect();
                keys.sort_unstable();
                out.steps.push((
                    d.snapshot
                        .frame_summary
                        .instruments
                        .iter()
                        .map(|r| r.force_n)
                        .collect(),
                    keys,
                ));
            },
            &mut answers,
        );
        out.t.push(t);
        out.force
            .push(answers.iter().map(|a| a.force.force_n).collect());
        out.flags
            .push(answers.iter().fold(0, |f, a| f | a.force.flags));
        if let Some((engine, snap)) = full.as_mut() {
            let all: Vec<Isometry3<f64>> = (0..n)
                .map(|i| tracks.get(i).map_or(home_pose(scene, i), |tr| tr[j]))
                .collect();
            let (next, report) = engine.step(snap, t, &all, vec![None; n]);
            assert!(report.is_some(), "the full solve at t = {t} s failed");
            *snap = next;
            out.full.push(
                (0..tracks.len())
                    .map(|i| snap.frame_summary.instruments[i].force_n)
                    .collect(),
            );
        }
    }
    out
}

/// The bundled `v-valley-insert-left` trajectory: times (s) and poses.
fn v_valley_insertion() -> (Vec<f64>, Vec<Isometry3<f64>>) {
    let text = include_str!("../../../client-cli/trajectories/v-valley-insert-left.csv");
    let mut ts = Vec::new();
    let mut track = Vec::new();
    for line in text.lines().skip(1) {
        let v: Vec<f64> = line
            .split(',')
            .map(|x| x.parse().expect("a number"))
            .collect();
        ts.push(v[0]);
        track.push(Isometry3::from_parts(
            Translation3::new(v[1], v[2], v[3]),
            UnitQuaternion::new_normalize(Quaternion::new(v[4], v[5], v[6], v[7])),
        ));
    }
    (ts, track)
}

/// Sample times `0, dt, ...` up to `end_s`.
fn times(end_s: f64, dt_s: f64) -> Vec<f64> {
    (0..=((end_s / dt_s).round() as usize))
        .map(|k| k as f64 * dt_s)
        .collect()
}

/// Smooth 0 -> 1 (cosine ramp) on `[a, b]`.
fn ramp(t: f64, a: f64, b: f64) -> f64 {
    let s = ((t - a) / (b - a)).clamp(0.0, 1.0);
    0.5 - 0.5 * (std::f64::consts::PI * s).cos()
}

/// Depth of face A below the cube's top at `t` for a press to `depth_m`
/// over `[0.05, 0.3]` s, held to 0.4 s, lifted over `[0.4, 0.65]` s; it
/// starts and ends 0.5 mm above the top.
fn press_depth(t: f64, depth_m: f64) -> f64 {
    let lift = 0.0005;
    -lift + (depth_m + lift) * (ramp(t, 0.05, 0.3) - ramp(t, 0.4, 0.65))
}

/// Frictionless press and retraction of one plate on the cube: the force at
/// a depth on the way out equals the force at that depth on the way in
/// (within 1% of the peak), it is non-zero at every depth below the rest
/// top, and exactly zero once the plate is above it.
#[test]
fn frictionless_retraction_retraces_pressing_and_lets_go_at_the_rest_surface() {
    let scene = cube(&[]);
    let ts = times(0.7, 0.002);
    let depth: Vec<f64> = ts.iter().map(|&t| press_depth(t, 0.003)).collect();
    let track: Vec<Isometry3<f64>> = depth
        .iter()
        .map(|d| flat(0.011, 0.005, TOUCH_Z - d))
        .collect();
    let r = run(&scene, &ts, &[track], false);
    let f: Vec<f64> = r.force.iter().map(|v| v[0].z).collect();
    let peak = f.iter().copied().fold(0.0, f64::max);
    assert!(peak > 0.05, "a 3 mm press pushes back: peak {peak} N");
    for (k, (&d, fk)) in depth.iter().zip(&r.force).enumerate() {
        let fk = fk[0];
        assert!(
            fk.x.abs() + fk.y.abs() <= 1e-9 * peak,
            "t = {}: tangential force {fk:?}",
            r.t[k]
        );
        if d < 0.0 {
            assert_eq!(
                fk.z, 0.0,
                "t = {}: {d} m above the top, force {}",
                r.t[k], fk.z
            );
        } else if d > 2e-5 {
            assert!(fk.z > 0.0, "t = {}: {d} m deep, force {}", r.t[k], fk.z);
        }
    }
    // The press branch (t < 0.3 s), increasing in depth, interpolated at
    // the retraction's depths.
    let press: Vec<(f64, f64)> = (0..ts.len())
        .filter(|&k| ts[k] > 0.05 && ts[k] <= 0.3)
        .map(|k| (depth[k], f[k]))
        .collect();
    let at = |d: f64| -> f64 {
        let i = press.partition_point(|p| p.0 < d).clamp(1, press.len() - 1);
        let (a, b) = (press[i - 1], press[i]);
        a.1 + (b.1 - a.1) * (d - a.0) / (b.0 - a.0)
    };
    let mut worst = 0.0f64;
    for k in (0..ts.len()).filter(|&k| ts[k] > 0.4 && ts[k] < 0.65 && depth[k] > 2.5e-4) {
        worst = worst.max((f[k] - at(depth[k])).abs() / peak);
    }
    // Frictionless quasi-static contact retraces exactly (up to the
    // interpolation between the press branch's samples).
    assert!(
        worst <= 0.01,
        "retraction differs from pressing by {worst} of the peak"
    );
}

/// A plate larger than the cube's top, the bottom fixed, `nu = 0`: uniaxial
/// strain, exact for linear tetrahedra, so the force is `E A d / L` and has
/// no tangential part.
#[test]
fn plate_larger_than_the_block_with_nu_zero_gives_e_a_d_over_l() {
    let scene = cube(&[
        ("poisson_ratio = 0.45", "poisson_ratio = 0.0"),
        ("width_m = 0.010", "width_m = 0.060"),
        ("length_m = 0.030", "length_m = 0.060"),
        ("nodes_per_face = 150", "nodes_per_face = 600"),
    ]);
    let d = 0.001;
    let ts = times(0.1, 0.002);
    let track: Vec<Isometry3<f64>> = ts
        .iter()
        .map(|&t| {
            flat(
                0.02,
                -0.01,
                TOUCH_Z + 0.0005 - (d + 0.0005) * ramp(t, 0.0, 0.05),
            )
        })
        .collect();
    let r = run(&scene, &ts, &[track], false);
    let f = r.force.last().expect("samples")[0];
    let expected = 3000.0 * 0.04 * 0.04 * d / 0.04;
    assert!(
        (f.z - expected).abs() <= 1e-6 * expected,
        "F_z = {} N, E A d / L = {expected} N",
        f.z
    );
    assert!(f.x.hypot(f.y) <= 1e-9 * expected, "tangential {f:?}");
}

/// A plate centred on the cube's top pressed 2 mm: by symmetry and without
/// friction the tangential force is below 1% of the normal.
#[test]
fn symmetric_frictionless_indentation_has_no_tangential_force() {
    let scene = cube(&[]);
    let ts = times(0.35, 0.002);
    let track: Vec<Isometry3<f64>> = ts
        .iter()
        .map(|&t| flat(0.02, 0.005, TOUCH_Z + 0.0005 - 0.0025 * ramp(t, 0.0, 0.3)))
        .collect();
    let r = run(&scene, &ts, &[track], false);
    let f = r.force.last().expect("samples")[0];
    assert!(f.z > 0.01, "pushes back: {f:?}");
    assert!(f.x.hypot(f.y) < 0.01 * f.z, "tangential {f:?}");
}

/// Two plates on the cube, one pressing in while the other lifts out (the
/// cross term of the two contacts is what a force loop holding the other
/// hand still would miss): every sample equals a full solve at that
/// sample's poses, and no sample is flagged.
#[test]
fn two_instruments_moving_in_opposite_directions_each_sample_equals_a_full_solve() {
    let scene = cube(&[]);
    let ts = times(0.3, 0.002);
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for &t in &ts {
        let s = ramp(t, 0.1, 0.3);
        let into = ramp(t, 0.0, 0.1);
        left.push(flat(
            0.011,
            0.005,
            TOUCH_Z + 0.0005 - (0.0015 + 0.0015 * s) * into - 0.0005 * into,
        ));
        right.push(flat(
            0.029,
            0.005,
            TOUCH_Z + 0.0005 - (0.003 - 0.0015 * s) * into - 0.0005 * into,
        ));
    }
    let r = run(&scene, &ts, &[left, right], true);
    let peak = r
        .full
        .iter()
        .flatten()
        .map(|f| f.norm())
        .fold(0.0, f64::max);
    assert!(peak > 0.05, "peak {peak} N");
    let mut worst = (0.0, 0.0);
    for (k, (s, f)) in r.force.iter().zip(&r.full).enumerate() {
        for i in 0..2 {
            let e = (s[i] - f[i]).norm() / peak;
            if e > worst.0 {
                worst = (e, r.t[k]);
            }
        }
        assert_eq!(r.flags[k], 0, "t = {}: flags {}", r.t[k], r.flags[k]);
    }
    // The law is equality, to the contact solver's tolerance: on the rest
    // geometry a sample's rows are the full solve's.
    assert!(
        worst.0 <= 1e-6,
        "a sample differs from the full solve by {} of the peak (t = {} s)",
        worst.0,
        worst.1
    );
}

/// The paper's V-shaped block, the plate inserted and then held still at one
/// pose (the bundled `v-valley-insert-left`): over the hold every
/// deformation step has the same contact set and the force varies by less
/// than 1% (the force loop's samples and the steps alike).
#[test]
fn a_plate_held_still_in_the_v_valley_settles() {
    let (scene, _) = Scene::load("v-valley").expect("bundled scene");
    let (ts, track) = v_valley_insertion();
    // The hold: the last stretch with the pose unchanged.
    let last = *track.last().expect("poses");
    let hold_from = ts[track
        .iter()
        .rposition(|p| {
            (p.translation.vector - last.translation.vector).norm() > 1e-12
                || p.rotation.angle_to(&last.rotation) > 1e-12
        })
        .map_or(0, |k| k + 1)];
    let end = *ts.last().expect("times");
    assert!(end - hold_from >= 0.2, "hold of {} s", end - hold_from);
    let r = run(&scene, &ts, &[track], false);
    // Skip the first 100 ms of the hold (the tissue's own settling).
    let settle = hold_from + 0.1;
    let held: Vec<f64> =
        r.t.iter()
            .zip(&r.force)
            .filter(|(t, _)| **t >= settle)
            .map(|(_, f)| f[0].norm())
            .collect();
    let mean = held.iter().sum::<f64>() / held.len() as f64;
    assert!(mean > 1e-3, "the held plate is in contact: {mean} N");
    let spread = held.iter().fold(0.0f64, |m, f| m.max((f - mean).abs())) / mean;
    assert!(spread < 0.01, "held force varies by {spread} of its mean");
    let dt = scene.loops.deformation_interval_s;
    let steps_in_hold: Vec<&(Vec<Vector3<f64>>, Vec<u64>)> = r
        .steps
        .iter()
        .enumerate()
        .filter(|(k, _)| (*k as f64 + 1.0) * dt >= settle)
        .map(|(_, s)| s)
        .collect();
    assert!(
        steps_in_hold.len() >= 5,
        "{} steps in the hold",
        steps_in_hold.len()
    );
    for w in steps_in_hold.windows(2) {
        assert_eq!(w[0].1, w[1].1, "the contact set changed during the hold");
        let (a, b) = (w[0].0[0].norm(), w[1].0[0].norm());
        assert!((a - b).abs() <= 0.01 * mean, "step forces {a} and {b} N");
    }
}

/// The bundled V-block insertion (the plate slides down between the walls,
/// its outline crossing the walls' triangles): every force sample equals a
/// full solve at its pose, and no step pushes one surface vertex with both
/// large faces of the plate (which would pinch it through the plate).
/// The law is equality, to the contact solver's tolerance: within 1e-6
/// of the peak (6e-14 measured; the polygon points slide on their
/// triangles at every sample, and their rows of `W` follow them exactly).
#[test]
fn every_sample_of_the_v_valley_insertion_equals_a_full_solve() {
    let (scene, _) = Scene::load("v-valley").expect("bundled scene");
    let (ts, track) = v_valley_insertion();
    let r = run(&scene, &ts, &[track], true);
    let peak = r.full.iter().map(|f| f[0].norm()).fold(0.0, f64::max);
    assert!(peak > 0.05, "the plate meets the walls: peak {peak} N");
    for k in 0..r.force.len() {
        assert_sample_is_the_full_solve(&r, k, peak);
        assert_eq!(r.flags[k], 0, "t = {}: flags {}", r.t[k], r.flags[k]);
    }
    // Row keys: node << 32 | owner << 16 | face << 12 | component; face 0
    // is A, 1 is B; node rows have components below 64.
    for (k, (_, keys)) in r.steps.iter().enumerate() {
        let node_rows = |face: u64| -> Vec<u64> {
            keys.iter()
                .filter(|&&key| (key >> 12) & 0xf == face && key & 0xfff < 64)
                .map(|&key| key >> 32)
                .collect()
        };
        let (a, b) = (node_rows(0), node_rows(1));
        assert!(
            a.iter().all(|n| !b.contains(n)),
            "step {k}: a vertex pushed by both large faces"
        );
    }
}

/// Coulomb friction (`mu = 0.3`): a plate pressed 1 mm into the cube and
/// dragged 6 mm along +x. Once the whole contact slides, every contact is
/// on the edge of its cone, so the tangential force is `mu` times the
/// normal force (the plate's outline carries its share of both), and it
/// opposes the drag, all along the slide: contacts that start under the
/// plate as it moves on (or whose row changes from a vertex's to a
/// point's) slide with the rest. (The search runs on the dragged shape:
/// `auto` geometry with friction.)
#[test]
fn a_plate_dragged_with_friction_slides_with_mu_times_the_normal_force() {
    let mu = 0.3;
    let scene = cube(&[(
        "[collision]",
        "[contact]\nlaw = \"coulomb\"\nfriction_coefficient = 0.3\n\n[collision]",
    )]);
    let ts = times(0.5, 0.005);
    let track: Vec<Isometry3<f64>> = ts
        .iter()
        .map(|&t| {
            flat(
                0.02 + 0.006 * ramp(t, 0.15, 0.5),
                0.005,
                TOUCH_Z + 0.0005 - 0.0015 * ramp(t, 0.0, 0.1),
            )
        })
        .collect();
    let r = run(&scene, &ts, &[track], false);
    // Every sample, sticking, at the onset of slip and sliding: the net
    // force lies in the cone (|sum F_t| <= sum |F_t,i| <= mu sum F_n,i).
    // (A sample whose contact problem goes unsolved, flagged, holds the
    // last solved force, which lay in the cone too.)
    for (j, &t) in r.t.iter().enumerate() {
        let f = r.force[j][0];
        assert!(
            f.x.hypot(f.y) <= mu * f.z.max(0.0) * (1.0 + 1e-6) + 1e-12,
            "t {t} s: |F_t| = {} above mu F_n = {}",
            f.x.hypot(f.y),
            mu * f.z
        );
    }
    let mut slid = 0;
    for (j, &t) in r.t.iter().enumerate() {
        if !(0.3..=0.5).contains(&t) {
            continue;
        }
        let f = r.force[j][0];
        let ft = f.x.hypot(f.y);
        assert!(f.z > 0.01, "t {t} s: pushes back: {f:?}");
        assert!(f.x < 0.0, "t {t} s: the tissue holds the plate back: {f:?}");
        assert!(
            (ft / f.z - mu).abs() < 0.02 * mu,
            "t {t} s: |F_t| / F_n = {} (mu {mu}): {f:?}",
            ft / f.z
        );
        slid += 1;
    }
    assert!(slid >= 40, "{slid} samples while sliding");
}

/// The cube pressed 3 mm by one plate, stepped in eight full solves, with
/// the cube's scene text extended by `extra`: the model and the last
/// snapshot.
fn pressed_cube(extra: &str) -> (Arc<Model>, fissure_engine::sim::core::snapshot::Snapshot) {
    let (model, snap, _) = pressed_cube_columns(extra);
    (model, snap)
}

/// [`pressed_cube`], and the nodes whose compliance columns the steps solved.
fn pressed_cube_columns(
    extra: &str,
) -> (
    Arc<Model>,
    fissure_engine::sim::core::snapshot::Snapshot,
    u64,
) {
    let text = format!("{}\n{extra}", include_str!("../../scenes/cube.toml"));
    let scene = Scene::parse(&text, "cube (skull variant)").expect("the variant parses");
    let model = Arc::new(Model::build(&scene).expect("the model builds"));
    let mut engine = StepEngine::new(&scene, model.clone(), ColumnPolicy::Compute, None, None)
        .expect("the engine starts");
    let mut snap = engine.rest(0.0);
    let n = scene.instruments.len();
    let mut columns = 0;
    for k in 1..=8 {
        let mut poses: Vec<Isometry3<f64>> = (0..n).map(|i| home_pose(&scene, i)).collect();
        poses[0] = flat(0.02, 0.005, TOUCH_Z - 0.003 * k as f64 / 8.0);
        let (next, report) = engine.step(&snap, 0.02 * k as f64, &poses, vec![None; n]);
        columns = report.expect("the step solves").columns_solved;
        snap = next;
    }
    (model, snap, columns)
}

/// The skull surface's nodes hold their normal compliance from load
/// (DESIGN.md section 3c): pressed with tens of skull rows pushing, the
/// steps solve no more compliance columns than without the skull (those of
/// the plate's nodes and their patch), and the skull rows have no row
/// pending.
#[test]
fn the_skull_surface_costs_the_steps_no_compliance_column() {
    let (_, _, free) = pressed_cube_columns("");
    let (_, held, with_skull) = pressed_cube_columns("[skull.surface]\ncsf_gap_m = 5e-5\n");
    let fm = &held.force_model;
    let pushing = fm
        .step_rows
        .iter()
        .zip(&fm.step_lambda)
        .filter(|(r, l)| r.owner == fissure_engine::sim::core::rows::SKULL_OWNER && **l > 0.0)
        .count();
    assert!(pushing >= 10, "{pushing} skull rows push");
    assert!(free > 0);
    assert!(
        with_skull <= free,
        "columns with the skull {with_skull}, without {free}"
    );
}

/// With the skull surface held by normal compliance, a plate held still
/// in a press: every force sample equals a full solve at its pose (the
/// force loop's patch gives the held nodes' blocks along their normals,
/// and the skull's contact set is the last step's, which at a still pose
/// is the full solve's).
#[test]
fn with_the_skull_surface_a_sample_of_a_held_press_equals_a_full_solve() {
    let text = format!(
        "{}\n[skull.surface]\ncsf_gap_m = 5e-5\n",
        include_str!("../../scenes/cube.toml")
    );
    let scene = Scene::parse(&text, "cube (skull variant)").expect("the variant parses");
    let ts = times(0.37, 0.005);
    let track: Vec<Isometry3<f64>> = ts
        .iter()
        .map(|&t| flat(0.02, 0.005, TOUCH_Z - press_depth(t.min(0.3), 0.003)))
        .collect();
    let r = run(&scene, &ts, &[track], true);
    let peak = r.full.iter().map(|f| f[0].norm()).fold(0.0, f64::max);
    assert!(peak > 0.05, "the plate presses: peak {peak} N");
    let mut held = 0;
    for k in 0..r.force.len() {
        // Still from 0.3 s; two steps at the still pose first.
        if r.t[k] < 0.345 {
            continue;
        }
        held += 1;
        assert_sample_is_the_full_solve(&r, k, peak);
    }
    assert!(held >= 4, "{held} samples held still");
}

/// The skull surface (the rest surface offset outward by the CSF gap,
/// frictionless and unilateral): pressed, the cube bulges sideways by more
/// than a 50 um gap without it; with it every supported node stays inside
/// the skull (`n . u <= g` within 1 nm), the skull only pushes (every
/// multiplier >= 0, some > 0) and only along each node's inward normal (no
/// tangential force); nodes of a region named open pass through it.
#[test]
fn the_skull_surface_holds_every_node_inside_it_pushing_only_inwards_along_its_normal() {
    let gap = 5e-5;
    let (model, free) = pressed_cube("");
    let skull = format!("[skull.surface]\ncsf_gap_m = {gap}\n");
    let (held_model, held) = pressed_cube(&skull);
    let s = held_model
        .skull_surface
        .as_ref()
        .expect("the scene has a skull surface");
    assert!(!s.nodes.is_empty());
    let bulge = |u: &[Vector3<f64>]| {
        s.nodes
            .iter()
            .map(|(v, n)| n.dot(&u[*v as usize]))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    assert!(
        bulge(&free.displacements) > 2.0 * gap,
        "without the skull the cube bulges past the gap: {} m",
        bulge(&free.displacements)
    );
    assert!(
        bulge(&held.displacements) <= gap + 1e-9,
        "inside the skull: {} m (gap {gap} m)",
        bulge(&held.displacements)
    );
    let fm = &held.force_model;
    let mut pushing = 0;
    for (r, l) in fm.step_rows.iter().zip(&fm.step_lambda) {
        if r.owner != fissure_engine::sim::core::rows::SKULL_OWNER {
            continue;
        }
        assert!(
            *l >= 0.0,
            "the skull never pulls: {l} N at node {}",
            r.row.node
        );
        let n = s
            .nodes
            .iter()
            .find(|(v, _)| *v == r.row.node)
            .expect("a skull row belongs to a supported node")
            .1;
        assert!(
            (r.row.dir + n).norm() < 1e-15,
            "along -n only: {:?}",
            r.row.dir
        );
        pushing += usize::from(*l > 0.0);
    }
    assert!(pushing > 0, "the skull holds the bulge");
    assert_eq!(model.skull_surface, None);
    // Open over the whole block: no node is held.
    let (open_model, open) = pressed_cube(&format!(
        "{skull}open = [{{ box_min_m = [-1.0, -1.0, -1.0], box_max_m = [1.0, 1.0, 1.0] }}]\n"
    ));
    assert!(open_model.skull_surface.as_ref().unwrap().nodes.is_empty());
    assert!((bulge(&open.displacements) - bulge(&free.displacements)).abs() < 1e-12);
}

/// The skull's own band sets the work, not the answer: the cube pressed
/// under a 50 um CSF gap with the skull band as wide as the contact band
/// (every supported node has a row in every step), at its default (half
/// the gap) and at 1 um (nodes join only once a solve pushes them through
/// the skull) ends in the same shape (the frictionless contact problem has
/// one solution), within 1e-9 of the largest displacement, and with fewer
/// skull rows the narrower the band.
#[test]
fn the_skull_band_changes_the_rows_a_step_solves_not_its_answer() {
    let skull_rows = |s: &fissure_engine::sim::core::snapshot::Snapshot| {
        s.force_model
            .step_rows
            .iter()
            .filter(|r| r.owner == fissure_engine::sim::core::rows::SKULL_OWNER)
            .count()
    };
    let press = |band: &str| pressed_cube(&format!("[skull.surface]\ncsf_gap_m = 5e-5\n{band}"));
    let (_, wide) = press("band_m = 1e-3");
    let (_, default) = press("");
    let (_, narrow) = press("band_m = 1e-6");
    let scale = wide
        .displacements
        .iter()
        .map(|u| u.norm())
        .fold(0.0, f64::max);
    assert!(scale > 1e-3, "the plate presses: {scale} m");
    for (name, s) in [("default", &default), ("1 um", &narrow)] {
        let diff = s
            .displacements
            .iter()
            .zip(wide.displacements.iter())
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(
            diff <= 1e-9 * scale,
            "band {name}: {diff} m from the wide band's shape"
        );
    }
    let rows = [skull_rows(&wide), skull_rows(&default), skull_rows(&narrow)];
    assert!(
        rows[0] > rows[1] && rows[1] >= rows[2] && rows[2] > 0,
        "skull rows wide / default / 1 um: {rows:?}"
    );
}

/// The `sylvian` scene on the coarse phantom with one spatula (`left`),
/// its fissure's walls joined by trabeculae of rupture strain `rupture`.
fn sylvian_with_ties(rupture: f64) -> Scene {
    let text = include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse");
    let cut = text.rfind("[[instrument]]").expect("two instruments");
    let text = format!(
        "{}\n[[ties]]\nkind = \"trabecula\"\nregion = {{ landmark = \"sylvian-left\" }}\ndensity_per_mm2 = 0.2\nseed = 3\nstiffness_n_per_m = 0.5\nrupture_strain = {rupture}\nmax_gap_m = 0.010\n",
        &text[..cut]
    );
    Scene::parse(&text, "sylvian with ties (test variant)").expect("the variant parses")
}

/// The left spatula inserted 20 mm into the coarse phantom's Sylvian
/// fissure (6.5 mm wide), lifted by 5 mm along +z over 0.3 s.
fn lift_in_fissure(scene: &Scene, ts: &[f64]) -> Vec<Isometry3<f64>> {
    ts.iter()
        .map(|&t| Translation3::new(0.020, 0.0, 0.005 * ramp(t, 0.0, 0.3)) * home_pose(scene, 0))
        .collect()
}

/// Ties are rows of the same contact problem in both loops: with the
/// fissure's walls tied, every force sample of an opening equals a full
/// solve at its pose (the ties as they are: intact, strong enough not to
/// tear here).
#[test]
fn with_ties_every_sample_of_an_opening_equals_a_full_solve() {
    let scene = sylvian_with_ties(100.0);
    let ts = times(0.3, 0.002);
    let r = run(&scene, &ts, &[lift_in_fissure(&scene, &ts)], true);
    let peak = r.full.iter().map(|f| f[0].norm()).fold(0.0, f64::max);
    assert!(peak > 0.05, "the plate opens the fissure: peak {peak} N");
    for k in 0..r.force.len() {
        assert_sample_is_the_full_solve(&r, k, peak);
    }
}

/// Tearing is part of the step: a stepped replay that tears ties gives
/// the same samples bit for bit, and the same releases.
#[test]
fn stepped_replays_that_tear_ties_are_bit_identical() {
    let scene = sylvian_with_ties(0.2);
    let ts = times(0.3, 0.002);
    let track = lift_in_fissure(&scene, &ts);
    let a = run(&scene, &ts, std::slice::from_ref(&track), false);
    let b = run(&scene, &ts, &[track], false);
    assert_eq!(a.force, b.force);
    assert_eq!(a.steps, b.steps);
    // Some ties tore: the tie rows with a force at the end are fewer than
    // at the start of the lift.
    let tie_rows = |keys: &[u64]| {
        keys.iter()
            .filter(|&&k| (k >> 16) & 0xffff == (u16::MAX - 2) as u64)
            .count()
    };
    let most = a.steps.iter().map(|s| tie_rows(&s.1)).max().unwrap_or(0);
    let last = tie_rows(&a.steps.last().expect("steps").1);
    assert!(
        most > 0 && last < most,
        "tie rows with force: most {most}, last {last}"
    );
}

/// `sylvian_with_ties`, with a second instrument: a blade (0.5 mm thick,
/// 8 mm wide) at the spatula's side of the fissure (y = 18 mm), outside it.
fn sylvian_with_blade(rupture: f64) -> Scene {
    let base = sylvian_with_ties(rupture);
    let mut text = include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse");
    let cut = text.rfind("[[instrument]]").expect("two instruments");
    text.truncate(cut);
    text.push_str(
        "[[instrument]]\nname = \"blade\"\nshape = \"blade\"\nthickness_m = 0.0005\nwidth_m = 0.008\nlength_m = 0.030\nnodes_per_face = 60\nhome_position_m = [-0.1007, 0.018, 0.0]\nhome_orientation = [0.0, 0.7071067811865476, 0.0, 0.7071067811865476]\n",
    );
    let mut scene = Scene::parse(&text, "sylvian with a blade (test variant)").expect("parses");
    scene.ties = base.ties;
    scene
}

/// The spatula lifts a tied wall and holds; mid-way between two steps the
/// blade enters the fissure 25 mm in one sample (a travel no sampled
/// position test could follow) and cuts the trabeculae its tip edge sweeps
/// across. The cut takes effect in that very sample: the held spatula's
/// force falls at once, before any step, and stays down after the steps
/// take the cut in (the ties the edge crosses: `collide_sweep` checks the
/// swept test against a brute-force solve).
#[test]
fn a_blade_cuts_the_ties_its_edge_sweeps_and_the_held_force_falls_in_the_next_sample() {
    let scene = sylvian_with_blade(100.0);
    let ts = times(0.4, 0.002);
    let spatula = lift_in_fissure(&scene, &ts);
    let cut_at = 0.330;
    let blade: Vec<Isometry3<f64>> = ts
        .iter()
        .map(|&t| {
            let into = if t >= cut_at - 1e-9 { 0.025 } else { 0.0 };
            Translation3::new(into, 0.0, 0.0) * home_pose(&scene, 1)
        })
        .collect();
    let r = run(&scene, &ts, &[spatula.clone(), blade], false);
    let k = ts
        .iter()
        .position(|&t| t >= cut_at - 1e-9)
        .expect("cut sample");
    let before = r.force[k - 1][0].z;
    let at = r.force[k][0].z;
    let after = r.force.last().expect("samples")[0].z;
    assert!(before < -0.05, "the spatula holds the wall: {before} N");
    // No step between samples k - 1 and k (steps every 20 ms, at 0.32 and
    // 0.34 s): the fall is the force loop's own.
    assert!(
        at > before + 0.01 * before.abs(),
        "the cut shows in the cutting sample: {before} N then {at} N"
    );
    assert!(
        after > before,
        "after the steps: {after} N, before the cut {before} N"
    );
    // Against the same run without the blade moving: the same force before
    // the cut, less after.
    let still: Vec<Isometry3<f64>> = ts.iter().map(|_| home_pose(&scene, 1)).collect();
    let uncut = run(&scene, &ts, &[spatula, still], false);
    assert_eq!(uncut.force[k - 1][0], r.force[k - 1][0]);
    assert!(uncut.force.last().expect("samples")[0].z < after);
}

/// A careless opening: the spatula lifts the wall against a few stiff
/// bridging vessels until one tears. From the step that tore it on, every
/// sample of the spatula carries the vessel-torn safety flag; none before.
#[test]
fn tearing_a_vessel_flags_the_samples_of_the_instrument_that_tore_it() {
    let mut scene = sylvian_with_ties(100.0);
    let text = "[[ties]]\nkind = \"vessel\"\nregion = { landmark = \"sylvian-left\" }\ndensity_per_mm2 = 0.01\nseed = 5\nstiffness_n_per_m = 50.0\nrupture_force_n = 0.02\nmax_gap_m = 0.010\n";
    let extra: Scene = Scene::parse(
        &format!(
            "{}\n{text}",
            include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse")
        ),
        "vessels",
    )
    .expect("parses");
    scene.ties.extend(extra.ties);
    let ts = times(0.3, 0.002);
    let r = run(&scene, &ts, &[lift_in_fissure(&scene, &ts)], false);
    const VESSEL_TORN: u32 = 128;
    let first = r
        .flags
        .iter()
        .position(|f| f & VESSEL_TORN != 0)
        .expect("a vessel tore");
    assert!(first > 0, "torn before the spatula moved");
    assert!(
        r.flags[first..].iter().all(|f| f & VESSEL_TORN != 0),
        "the flag stays"
    );
}
