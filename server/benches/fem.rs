//! Criterion benchmarks of one deformation step per strategy on a 6,000-tet
//! cube (bottom fixed, 50 top vertices indented). The 48k-tet figures come
//! from `fissure_cli::lab::bench::fem`.

use criterion::{Criterion, criterion_group, criterion_main};
use fissure_engine::fem::{Material, Prescribed, SolverOptions, Strategy, build_solver};
use fissure_engine::mesh::blocks::cube;
use nalgebra::{Point3, Vector3};
use std::hint::black_box;

fn step(c: &mut Criterion) {
    let l = 0.05;
    let mesh = cube(l, 10);
    let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z < 1e-12)
        .collect();
    let top = Point3::new(0.5 * l, 0.5 * l, l);
    let mut surface = mesh.boundary().to_volume;
    surface.sort_by(|&a, &b| {
        (mesh.nodes[a as usize] - top)
            .norm()
            .total_cmp(&(mesh.nodes[b as usize] - top).norm())
    });
    let pres: Vec<Prescribed> = surface[..50]
        .iter()
        .map(|&node| Prescribed {
            node,
            displacement: Vector3::new(0.0, 0.0, -5e-4),
        })
        .collect();
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    let mut group = c.benchmark_group("fem_step_cube6k_50contacts");
    group.sample_size(10);
    for strategy in [
        Strategy::Direct,
        Strategy::Compliance,
        Strategy::Corotational,
    ] {
        let mut s =
            build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).expect("solver");
        s.solve(&pres).expect("warm-up step");
        group.bench_function(strategy.name(), |b| {
            b.iter(|| {
                black_box(s.solve(black_box(&pres)).expect("step").iterations);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, step);
criterion_main!(benches);
