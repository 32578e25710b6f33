use fissure_server::fem::compliance::ColumnPolicy;
use fissure_server::scene::Scene;
use fissure_server::sim::engine::Model;
use fissure_server::sim::stepped::SteppedRunner;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::sync::Arc;

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
    let scene_name = &args[1];
    let trajs: Vec<Vec<(f64, Isometry3<f64>)>> = args[2..].iter().map(|n| load(n)).collect();
    let (scene, _) = Scene::load(scene_name).unwrap();
    let model = Arc::new(Model::build(&scene).unwrap());
    let mut r = SteppedRunner::for_scene(&scene, model.clone(), ColumnPolicy::Compute).unwrap();
    let mut answers = Vec::new();
    let n = trajs[0].len();
    let stop: usize = std::env::var("AT")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .map(|a| a + 1)
        .unwrap_or(n);
    for j in 0..stop {
        let t = trajs[0][j].0;
        let poses: Vec<(usize, Isometry3<f64>)> = trajs
            .iter()
            .enumerate()
            .map(|(i, tr)| (i, tr[j.min(tr.len() - 1)].1))
            .filter(|(i, _)| {
                std::env::var("SKIP")
                    .ok()
                    .and_then(|v| v.parse::<usize>().ok())
                    != Some(*i)
            })
            .collect();
        answers.clear();
        r.tick(
            t,
            &poses,
            &mut |d| {
                if let Some(rep) = &d.report {
                    if d.snapshot.frame % 5 == 0 || std::env::var_os("EVERY").is_some() {
                        let fs: Vec<String> = d
                            .snapshot
                            .frame_summary
                            .instruments
                            .iter()
                            .map(|f| {
                                format!(
                                    "[{:.4} {:.4} {:.4}] c{} p{} pend{}",
                                    f.force_n.x,
                                    f.force_n.y,
                                    f.force_n.z,
                                    f.contact_vertices,
                                    f.pairs,
                                    f.pending_vertices
                                )
                            })
                            .collect();
                        println!(
                            "frame {} t {:.3} rows {} pending {} patch {} iters {} | {}",
                            d.snapshot.frame,
                            d.snapshot.sim_time_s,
                            rep.rows,
                            rep.pending,
                            rep.patch_nodes,
                            rep.iterations,
                            fs.join(" | ")
                        );
                    }
                } else {
                    println!(
                        "frame {} FAILED {:?}",
                        d.snapshot.frame, d.snapshot.solver_error
                    );
                }
            },
            &mut answers,
        );
        if std::env::var_os("ROWS").is_some() && j == n - 1
            || std::env::var_os("ROWS").is_some() && j == n - 21
        {
            let fm = &r.snapshot().force_model;
            for (row, l) in fm.step_rows.iter().zip(&fm.step_lambda) {
                println!(
                    "  key {:x} face {} point {} w {:.4?} gap {:.6} lambda {:.5}",
                    row.key,
                    (row.key >> 4) & 0xf,
                    row.row.is_point(),
                    row.triangle.1,
                    row.row.gap_free_m,
                    l
                );
            }
        }
        if j % 100 == 0 {
            let s: Vec<String> = answers
                .iter()
                .map(|a| {
                    format!(
                        "[{:.4} {:.4} {:.4}] c{} fl{}",
                        a.force.force_n.x,
                        a.force.force_n.y,
                        a.force.force_n.z,
                        a.force.contact_count,
                        a.force.flags
                    )
                })
                .collect();
            println!("t {t:.3} {}", s.join(" | "));
        }
    }
    let snap = r.snapshot().clone();
    let inst: usize = std::env::var("INST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let at: usize = std::env::var("AT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n - 1);
    let mut fl = fissure_server::sim::force_loop::ForceLoop::new(&scene, &model, inst, None);
    let pose = trajs[inst][at].1;
    fl.query(&model, &snap, &pose);
    let f = fl.solve(&model, &snap, &|_| None, &pose.translation.vector);
    println!("fresh loop force {:?}", f.force_n);
    let mut fr: Vec<_> = fl
        .rows()
        .iter()
        .map(|r| (r.key, r.row.gap_free_m, r.triangle.1))
        .collect();
    fr.sort_by_key(|x| x.0);
    let mut sr: Vec<_> = snap
        .force_model
        .step_rows
        .iter()
        .zip(&snap.force_model.step_lambda)
        .map(|(r, l)| (r.key, r.row.gap_free_m, r.triangle.1, *l))
        .collect();
    sr.sort_by_key(|x| x.0);
    let mut cq = fissure_server::sim::engine::ContactQuery::new(&scene, faer::Par::Seq);
    let mut h = fl.history().clone();
    let out = cq.query(&model, &snap, inst, &pose, &mut h);
    let tri: u32 = std::env::var("TRI")
        .ok()
        .and_then(|v| u32::from_str_radix(&v, 16).ok())
        .unwrap_or(0x38e);
    println!(
        "tri {:?} vol nodes {:?}",
        model.surface.triangles[tri as usize],
        model.surface.triangles[tri as usize].map(|v| model.surface.to_volume[v as usize])
    );
    for p in out.pairs.iter().filter(|p| p.triangle == tri) {
        println!("pair {p:?}");
    }
    for p in out.cancelled.iter().filter(|p| p.triangle == tri) {
        println!("cancelled {p:?}");
    }
    for e in out.edges.iter().filter(|p| p.triangle == tri) {
        println!("edge {e:?}");
    }
    for c in out.candidates.iter() {
        println!(
            "cand v{} vol{} face {:?} gap {:.6}",
            c.surface_vertex, c.volume_node, c.face, c.gap_now_m
        );
    }
    println!(
        "pairs {} cancelled {}",
        out.pairs.len(),
        out.cancelled.len()
    );
    for x in &fr {
        println!("loop {:x} gap {:.6} w {:.4?}", x.0, x.1, x.2);
    }
    for x in &sr {
        println!("step {:x} gap {:.6} w {:.4?} l {:.4}", x.0, x.1, x.2, x.3);
    }
}
