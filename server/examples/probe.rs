use faer::Par;
use fissure_server::collide::faces::FaceId;
use fissure_server::scene::Scene;
use fissure_server::sim::engine::{ContactQuery, Model};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

fn load(name: &str) -> Vec<(f64, Isometry3<f64>)> {
    let text = std::fs::read_to_string(format!("client-cli/trajectories/{name}.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (
                v[0],
                Isometry3::from_parts(
                    Translation3::new(v[1], v[2], v[3]),
                    UnitQuaternion::new_normalize(Quaternion::new(v[4], v[5], v[6], v[7])),
                ),
            )
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (scene, _) = Scene::load(&args[1]).unwrap();
    let tr = load(&args[2]);
    let t: f64 = args[3].parse().unwrap();
    let pose = tr
        .iter()
        .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
        .unwrap()
        .1;
    let model = Model::build(&scene).unwrap();
    let snap = model.rest_snapshot(&scene, 0, 0.0);
    let mut q = ContactQuery::new(&scene, Par::Seq);
    let mut h = model.new_history(0);
    // a few samples to set history
    for _ in 0..3 {
        q.query(&model, &snap, 0, &pose, &mut h);
    }
    let out = q.query(&model, &snap, 0, &pose, &mut h).clone();
    println!(
        "pairs {} cancelled {} cands {} nearby {}",
        out.pairs.len(),
        out.cancelled.len(),
        out.candidates.len(),
        out.nearby.len()
    );
    let inv = pose.inverse();
    let mut seen = std::collections::HashSet::new();
    for p in &out.pairs {
        let kind = model.instruments[0].nodes[p.node as usize].kind;
        for v in model.surface.triangles[p.triangle as usize] {
            if !seen.insert((v, FaceId::of(kind))) {
                continue;
            }
            let x = inv * snap.surface[v as usize];
            let plate = &model.instruments[0].plate;
            let fa = plate.project(FaceId::of(kind), &x);
            let ft = plate.project(FaceId::Tip, &x);
            println!(
                "pair node {:?} t {:.5} vertex {v} local {:.5} {:.5} {:.5} face gap {:.5} out {:.5} | tip gap {:.5} out {:.5}",
                kind, p.t, x.x, x.y, x.z, fa.gap_m, fa.outside_m, ft.gap_m, ft.outside_m
            );
        }
    }
    for c in &out.candidates {
        println!("cand {:?}", c);
    }
}
