use fissure_server::fem::compliance::ColumnPolicy;
use fissure_server::scene::Scene;
use fissure_server::sim::engine::{Model, StepEngine};
use fissure_server::sim::force_loop::ForceLoop;
use fissure_server::sim::stepped::SteppedRunner;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::sync::Arc;

fn flat(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::new_normalize(Quaternion::new(0.5, -0.5, 0.5, 0.5)),
    )
}
fn ramp(t: f64, a: f64, b: f64) -> f64 {
    let s = ((t - a) / (b - a)).clamp(0.0, 1.0);
    0.5 - 0.5 * (std::f64::consts::PI * s).cos()
}
const TOUCH_Z: f64 = 0.04 + 0.00075;
fn main() {
    let (scene, _) = Scene::load("cube").unwrap();
    let model = Arc::new(Model::build(&scene).unwrap());
    let mut runner =
        SteppedRunner::for_scene(&scene, model.clone(), ColumnPolicy::Compute).unwrap();
    let mut eng =
        StepEngine::new(&scene, model.clone(), ColumnPolicy::Compute, None, None).unwrap();
    let mut snap = eng.rest(0.0);
    let at: f64 = std::env::var("AT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.22);
    let mut answers = Vec::new();
    for k in 0..=150 {
        let t = k as f64 * 0.002;
        let s = ramp(t, 0.1, 0.3);
        let into = ramp(t, 0.0, 0.1);
        let l = flat(
            0.011,
            0.005,
            TOUCH_Z + 0.0005 - (0.0015 + 0.0015 * s) * into - 0.0005 * into,
        );
        let r = flat(
            0.029,
            0.005,
            TOUCH_Z + 0.0005 - (0.003 - 0.0015 * s) * into - 0.0005 * into,
        );
        answers.clear();
        runner.tick(t, &[(0, l), (1, r)], &mut |_| {}, &mut answers);
        let (next, _) = eng.step(&snap, t, &[l, r], vec![None, None]);
        snap = next;
        if (t - at).abs() < 1e-9 {
            println!(
                "sample {:?} {:?}",
                answers[0].force.force_n, answers[1].force.force_n
            );
            println!(
                "full {:?} {:?}",
                snap.frame_summary.instruments[0].force_n,
                snap.frame_summary.instruments[1].force_n
            );
            // a fresh loop on the runner's snapshot
            let rs = runner.snapshot().clone();
            let mut fl = ForceLoop::new(&scene, &model, 0, None);
            fl.query(&model, &rs, &l);
            let mut a: Vec<_> = fl
                .rows()
                .iter()
                .map(|r| (r.key, r.row.gap_free_m, r.triangle.1))
                .collect();
            a.sort_by_key(|x| x.0);
            let fm = &snap.force_model;
            let mut b: Vec<_> = fm
                .step_rows
                .iter()
                .zip(&fm.step_lambda)
                .filter(|(r, _)| r.owner == 0)
                .map(|(r, l)| (r.key, r.row.gap_free_m, r.triangle.1, *l))
                .collect();
            b.sort_by_key(|x| x.0);
            let bk: std::collections::HashMap<u64, _> = b.iter().map(|x| (x.0, *x)).collect();
            let ak: std::collections::HashMap<u64, _> = a.iter().map(|x| (x.0, *x)).collect();
            for x in &a {
                match bk.get(&x.0) {
                    Some(y) => {
                        if (x.1 - y.1).abs() > 1e-9 {
                            println!(
                                "diff {:x} loop gap {:.6} w {:.4?} full gap {:.6} w {:.4?} l {:.4}",
                                x.0, x.1, x.2, y.1, y.2, y.3
                            )
                        }
                    }
                    None => println!("loop only {:x} gap {:.6} w {:.4?}", x.0, x.1, x.2),
                }
            }
            for y in &b {
                if !ak.contains_key(&y.0) {
                    println!(
                        "full only {:x} gap {:.6} w {:.4?} l {:.4}",
                        y.0, y.1, y.2, y.3
                    )
                }
            }
            println!("loop rows {} full rows {}", a.len(), b.len());
        }
    }
}
